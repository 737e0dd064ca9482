"""The simulated base: wheels, slip, a gyro and ground truth, stepped in simulated time."""

__all__ = ['model']

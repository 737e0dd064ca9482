"""Velocity commands to wheel commands: the limits and the cmd_vel pipeline."""

__all__ = ['cmd_vel_pipeline', 'limits']

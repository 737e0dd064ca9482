"""Wheel readings to poses: encoders, config, stamps, timeline, gyro, estimator, pipeline."""

__all__ = [
    'config', 'encoders', 'estimator', 'gyro', 'pipeline', 'publication', 'stamps', 'timeline',
]

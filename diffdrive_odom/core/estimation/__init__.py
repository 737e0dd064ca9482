"""Wheel readings to poses: encoders, stamps, timeline, gyro, estimator, pipeline, publication."""

__all__ = ['encoders', 'estimator', 'gyro', 'pipeline', 'publication', 'stamps', 'timeline']

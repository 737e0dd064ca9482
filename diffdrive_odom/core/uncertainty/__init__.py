"""Pose covariance through each exact step: the model, and a stretch of steps at once."""

__all__ = ['fastcov', 'noise', 'propagation']

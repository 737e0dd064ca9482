"""Odometry against ground truth: metrics, calibration, held-out check, UMBmark, NEES."""

__all__ = ['calibration', 'consistency', 'crossval', 'determinacy', 'leftout', 'metrics',
           'recorded_run', 'umbmark']

"""Odometry against ground truth: metrics, the judge of a fit, calibration, UMBmark, NEES."""

__all__ = ['assessment', 'calibration', 'consistency', 'crossval', 'determinacy', 'judge',
           'leftout', 'metrics', 'objective', 'recorded_run', 'umbmark']

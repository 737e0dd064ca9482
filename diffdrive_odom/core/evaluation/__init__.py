"""Odometry against ground truth: metrics, recorded runs, calibration, held-out check, UMBmark."""

__all__ = ['calibration', 'crossval', 'determinacy', 'metrics', 'recorded_run', 'umbmark']

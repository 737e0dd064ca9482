"""Online self-calibration: the wheel geometry estimated while driving, from the gyro.

kalman (the scalar update both filters use), online_geometry (the ratios from the gyro's
judged steps), online_scale (the scale from a reference pose), ratios (the geometry's
uncertainty from the ratios' estimate), online_estimate (the estimate as published),
online_apply (which geometry the steps integrate with). It imports no other concern.
"""

__all__ = ['kalman', 'online_apply', 'online_estimate', 'online_geometry', 'online_scale',
           'ratios']

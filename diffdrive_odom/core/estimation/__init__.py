"""Wheel readings to poses, and the gyro and open loop beside them.

The wheels: encoders (decode, increments), timeline (verdicts), plausibility, estimator,
stamps; the gyro: imuinput, gyrosamples, gyro (gyrodometry), wheelturn (a real robot's
wheel turn), slips, slipstep, standstill, imulag; online self-calibration: kalman,
online_geometry, online_estimate, online_scale, online_apply; open loop: open_loop; the
node-facing shell: config, pipeline, results, gate, publication, setpose.
"""

__all__ = [
    'config', 'encoders', 'estimator', 'gate', 'gyro', 'gyrosamples', 'imuinput', 'imulag',
    'kalman', 'online_apply', 'online_estimate', 'online_geometry', 'online_scale',
    'open_loop', 'pipeline', 'plausibility', 'publication', 'results', 'setpose', 'slips',
    'slipstep', 'stamps', 'standstill', 'timeline', 'wheelturn',
]

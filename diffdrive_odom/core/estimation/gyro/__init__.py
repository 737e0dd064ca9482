"""Gyrodometry: the IMU's yaw rate beside the wheels, slips named when they happen.

config (its settings), imuinput (an IMU sample's checks), gyrosamples (the rates by
stamp), gyrodometry (each step's heading decided), wheelturn (a real robot's wheel turn
and its variance), slips (what counts as a slip event), slipstep (a slipping step's
distance), standstill (the bias while standing still), imulag (the IMU's stamps' lag).
It imports no other concern: it gives the estimator its headings through the wheels'
:class:`~diffdrive_odom.core.estimation.wheels.estimator.HeadingSource` (structurally:
the pipeline wires it in).
"""

__all__ = ['config', 'gyrodometry', 'gyrosamples', 'imuinput', 'imulag', 'slips', 'slipstep',
           'standstill', 'wheelturn']

"""calibrate's parts apart from its command line (:mod:`diffdrive_odom.tools.calibrate`).

The fits themselves are the core's (:mod:`diffdrive_odom.core.evaluation`); here bags
become the runs they fit, and their results become text. Imports the bag library below
it (past the parsing), never a command; this ``__init__`` imports nothing.

- :mod:`.runs`: a bag decoded into a run (wheel steps by the node's pipeline, the gyro's
  slips, the ground truth), and the gyro settings a bag with an IMU is decoded with
- :mod:`.report`: what calibrate prints (the held-out verdict, the fit, the params block)
"""

__all__ = ["report", "runs"]

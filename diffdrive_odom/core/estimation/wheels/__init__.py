"""The wheels' state machine: encoder readings to an integrated pose, a verdict for each.

config (the rules' settings), encoders (decode, increments), timeline (the verdicts and
the stamp rules' texts), plausibility (the one definition of an implausible step),
counts (what the counts did: the interval a step is judged over, what a gap held),
twist (the published twist's rolling mean), estimator (the rules in order, the
integration). It imports no other concern: a step's
heading from elsewhere (the gyro's) comes in through
:class:`~diffdrive_odom.core.estimation.wheels.estimator.HeadingSource`, which the
pipeline fills.
"""

__all__ = ['config', 'counts', 'encoders', 'estimator', 'plausibility', 'timeline', 'twist']

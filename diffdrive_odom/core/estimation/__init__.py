"""Wheel readings to poses: three sensor concerns side by side, a shell above them.

Sub-packages, each importing none of the others: wheels (encoders to a pose),
gyro (gyrodometry), online (online self-calibration); beside them open_loop (velocity
commands to poses). Below them, what they share: setpose (``~/set_pose``'s rule) and
stamps (which time a reading carries). Above them the shell the nodes and tools use:
config, gate, results, pipeline (which wires the gyro into the estimator), publication.
The order is an import-linter contract (``setup.cfg``).
"""

__all__ = [
    'config', 'gate', 'gyro', 'online', 'open_loop', 'pipeline', 'publication', 'results',
    'setpose', 'stamps', 'wheels',
]

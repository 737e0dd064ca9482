"""The bag library: rosbag2 (mcap, sqlite3) and ROS 1 bags read, written, recovered, converted.

Through rosbags (the ``tools`` extra), with no rclpy; it imports nothing of the commands
or of replay's engines above it, only :mod:`diffdrive_odom.tools.cmdline` below (the
contract in setup.cfg). This ``__init__`` imports nothing, so a command's ``--help``
needs no rosbags; callers import the module that defines what they use.

- reading: :mod:`.bagio` (opening a bag, its topics, :class:`~.bagio.BagError`),
  :mod:`.reorder` (the one stamp-order rule), :mod:`.bagreadings` (JointState, Imu and
  reference poses as readings, one by one), :mod:`.bagblocks` (the same readings in
  blocks), :mod:`.bagcommands` (velocity commands, for open loop), :mod:`.poses` (any
  pose topic as a trajectory; which one is the ground truth)
- writing: :mod:`.bagwriter` (rosbag2 by topic name), :mod:`.bulkmcap` (many rows into
  MCAP at once)
- :mod:`.rosbagsinternals`: every use of rosbags beyond its public API (the bulk
  writer's, recovery's, reindex's, the ROS 1 conversion's), checked name by name
- conversion: :mod:`.cdrconvert` (any bag's messages to ROS 2 CDR)
- recovery: :mod:`.recovery` (recordings cut short, read as they are), :mod:`.mcapscan`
  (a torn MCAP walked record by record), :mod:`.sqlitescan` (a malformed db3),
  :mod:`.reindexing` (what such a recording lacks, written: its metadata, a whole copy)
"""

__all__ = ["bagblocks", "bagcommands", "bagio", "bagreadings", "bagwriter", "bulkmcap",
           "cdrconvert", "mcapscan", "poses", "recovery", "reindexing",
           "reorder", "rosbagsinternals", "sqlitescan"]

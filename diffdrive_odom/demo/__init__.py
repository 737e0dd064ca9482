"""``diffdrive-odom demo`` (``make demo``): the whole product in one closed loop.

Kept import-light (no rclpy, no matplotlib): the pure parts (:mod:`.settings`,
:mod:`.report`, :mod:`.evaluation`, :mod:`.plot`) import without ROS. Callers import names from the
submodule that defines them.

- :mod:`.settings`: options, the params file of a run, the squares' paths, the topic table
- :mod:`.report`: recorded series, the rows, the results table (pure)
- :mod:`.evaluation`: calibration from the run (slip steps left out), the replays (pure)
- :mod:`.plot`: the picture (matplotlib, pure)
- :mod:`.children`: the four nodes as child processes (logs, stop on leaving)
- :mod:`.recorder`: this process's node (records the bag, sends the paths)
- :mod:`.loop`: the run (start, wait until up, drive the squares, evaluate)
- :mod:`.cli`: the command line
"""

__all__ = ["children", "cli", "evaluation", "interrupts", "loop", "plot", "recorder", "report",
           "settings"]

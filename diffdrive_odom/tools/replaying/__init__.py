"""replay's engines and outputs, apart from its command line (:mod:`diffdrive_odom.tools.replay`).

The engines feed a bag through the node's own core and hand each pose it would publish to
a sink; they import the bag library below them, never a command. This ``__init__`` imports
nothing, so the command's ``--help`` pays for none of it.

- :mod:`.readings`: the readings engine (wheel readings, gyro samples, reference poses
  through the node's pipeline; the fast lane in bulk)
- :mod:`.openloop`: the commands engine (``open_loop``: velocity commands, the node's timer)
- :mod:`.stats`: what a replay did (:class:`~.stats.ReplayStats`), which both engines fill
- :mod:`.bag`: one bag replayed into the outputs replay's flags name (staged), by either engine
- :mod:`.sinks`: where the published poses go (output bag, CSV, ``--eval``'s trajectory)
- :mod:`.csvout`: the CSV table, numbers written losslessly
- :mod:`.online_report`, :mod:`.online_plot`: ``--online-calibration``'s estimate, printed
  and drawn (the demo draws the same panel)
"""

__all__ = ["bag", "csvout", "online_plot", "online_report", "openloop", "readings", "sinks",
           "stats"]

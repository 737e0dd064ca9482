"""Offline tools and the ``diffdrive-odom`` command line: replay, eval, calibrate, play, reindex.

The commands are the modules here, each thin (its flags, its checks, what it prints):
:mod:`.cli` (the dispatch), :mod:`.replay`, :mod:`.evaluate`, :mod:`.calibrate`,
:mod:`.play`, :mod:`.reindex`, and :mod:`.fleet` (several bags at once). Below them, in
layers (setup.cfg's tools contract): :mod:`.replaying` and :mod:`.calibrating` (the
engines and outputs of replay and calibrate), :mod:`.bags` (the bag library: reading,
writing, conversion, recovery), :mod:`.cmdline` (what every command shares, pure).

May import: ``core``, ``settings``, ``wire`` and (for ``play``, the output files)
``ros``; never the demo, except the CLI's lazy dispatch to ``diffdrive_odom.demo.cli``.
"""

__all__ = ["bags", "calibrate", "calibrating", "cli", "cmdline", "evaluate", "fleet", "play",
           "reindex", "replay", "replaying"]

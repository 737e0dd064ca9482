"""Offline tools and the ``diffdrive-odom`` command line: bag I/O, replay, eval, calibrate, play.

May import: ``core``, ``settings`` and (for ``play``) ``ros``; never the demo, except the
CLI's lazy dispatch to ``diffdrive_odom.demo.cli``.
"""

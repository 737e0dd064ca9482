"""What every command shares, pure (standard library and ``settings``; no bag library).

So ``--help``, the argument checks and the demo's output directory work on a plain
install (no ``tools`` extra); the bag library reports through it too (:mod:`.once`).

- :mod:`.args`: the flags replay, calibrate and eval share, and the settings they give
- :mod:`.outputs`: output files checked before the work, staged, named at the end
- :mod:`.once`: lines a command says once (the ``[recovery]`` line of a bag opened again)
- :mod:`.progress`: replay's ``done/total`` line on stderr
- :mod:`.process`: stopping child processes (SIGINT, wait, SIGKILL)
"""

__all__ = ["args", "once", "outputs", "process", "progress"]

"""rig.hil — the hardware-in-the-loop path: the wire protocol (`protocol`), links to a
board (`links`: pty, QEMU, serial, cflib; `targets`: a target name to its link and
build; `zenoh`: boards served and reached on eclipse-zenoh), replay in lock-step and
real time (`replay`), the run record (`runrecord`), a replay session with its outputs
(`session`), many boards at once (`farm`), cost against a baseline (`bench`) and the
HTML report (`report`).

May import: `rig.data`, `rig.estimator`.
"""

"""rig.hil — the hardware-in-the-loop path: the wire protocol (`protocol`), links to a
board (`links`: pty, QEMU's USART socket and bulk-link pipes, serial, cflib; `targets`:
a target name to its link and build; `zenoh`: boards served and reached on
eclipse-zenoh), replay in lock-step and real time (`replay`), the run record
(`runrecord`, Foxglove's schemas in `foxglove`), one replay job with its outputs
(`job`), many boards at once (`farm`), cost against a baseline (`bench`), the checks
and JUnit (`checks`), signals (`interrupt`) and the HTML report (`report`, its charts
by `svgplot`), and the `board` fixture of the pytest plugin (`pytest_plugin`).

May import: `rig.data`, `rig.estimator`.
"""

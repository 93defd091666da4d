"""bridge — the `bridge` command (bridge.cli): one board served on eclipse-zenoh
(rig.hil.zenoh) so that many boards on many hosts report to one rig.

May import: `rig.hil`.
"""

"""bridge: serves board links on eclipse-zenoh (rig.hil.zenoh) so that many boards on
many hosts report to one rig; `bridge --help` (bridge.cli) runs one."""

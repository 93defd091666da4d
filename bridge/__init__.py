"""bridge: publishes a board's decoded stream on eclipse-zenoh (built in the rig-service issue)."""

"""The RM-65 controller's JSON-over-TCP protocol (messages, units, framing) and the blocking client that speaks it."""

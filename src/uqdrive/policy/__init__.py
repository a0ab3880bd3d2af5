"""What drives: one `Policy` interface that uqdrive's trained controllers, the autopilot and a user's policy
implement; draws of a decision and the warning rules that read them."""

"""What drives: the one `Policy` interface (`interface.py`) that uqdrive's trained controllers, its reference policies
and a user's policy implement, their picklable recipes and a user's policy files; draws of a decision and the warning
rules that read them."""

"""Acquisition as one wing: DAgger rounds where a controller's sweep found it unsafe (roll out there, label the
frames with the world's expert, retrain) and the before/after checks (`acquisition.py`), the acquire stage's schema and
plan (`plan.py`)."""

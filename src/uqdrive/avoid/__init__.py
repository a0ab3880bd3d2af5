"""Collision avoidance with warnings (the paper's second experiment): its plan, cells, calibration of the
warning rule, the replay of recorded rollouts through candidate rules, answers, records, files and figures."""

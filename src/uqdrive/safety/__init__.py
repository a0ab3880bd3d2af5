"""Closed-loop probabilistic safety η1: controllers, safe sets, rollouts, parallel executors, sweep cells,
and the three-tier warning system on real-time decision confidence η2.

Composes `sim` (the world), `models` (the posteriors) and `uq` (measures and estimators).
"""

"""Judging runs (pure: arrays and records in, plain records out): metrics, thesis claims, time-windowed
requirements, who wins and why, statistics, fault diagnosis, and which family applies to a case."""

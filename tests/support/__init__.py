"""Helpers shared by the tests (not tests themselves): waiting on a condition, the real scans,
reference implementations, format samples, hardware simulators."""

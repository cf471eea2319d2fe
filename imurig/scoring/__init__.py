"""Bring your own algorithm: score a user's calibrator or filter against the injected truth, in process or through files."""

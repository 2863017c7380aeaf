"""SCAN policy."""

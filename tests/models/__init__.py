"""Tests of aed_models: shared blocks, policies, detectors."""

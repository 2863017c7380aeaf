"""AED learners: policies and detectors."""

"""NaiveDC policy."""

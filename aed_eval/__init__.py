"""AED evaluation protocol and command line."""

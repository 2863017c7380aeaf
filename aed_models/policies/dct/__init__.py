"""DCT policy."""

"""The Zenoh processes (scan assembly, feature extraction, inference): thin wrappers over affordcore."""

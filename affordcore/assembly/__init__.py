"""Scans to a room: depth frames back-projected, registered by KISS-ICP, levelled, checkpointed."""

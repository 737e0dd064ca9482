"""Offline readings in bulk: blocks of readings, the fast lane over them, the batch path."""

__all__ = ['batch', 'fastlane', 'readings']

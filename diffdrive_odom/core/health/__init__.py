"""Each node's health verdict for /diagnostics, from plain counters."""

__all__ = ['base_diagnostics', 'diagnostics']

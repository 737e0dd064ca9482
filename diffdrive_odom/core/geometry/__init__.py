"""The plane's geometry: SE(2), 3x3 products, the kinematics, the exact CIR step, mounts."""

__all__ = ['integration', 'kinematics', 'mat3', 'mount', 'se2']

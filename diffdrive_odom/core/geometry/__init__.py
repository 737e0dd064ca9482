"""The plane's geometry: SE(2) poses, 3x3 products, the wheel kinematics and the exact CIR step."""

__all__ = ['integration', 'kinematics', 'mat3', 'se2']

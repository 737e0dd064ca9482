"""Where the robot should go: routes, the paths made of them and Kumar's path following."""

__all__ = ['path_following', 'paths', 'routes']

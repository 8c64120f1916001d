"""The one error of scene translation, raised wherever a stage cannot be rendered."""


class SceneError(Exception):
    """The scene cannot be rendered; the message says why, for the person who sent it."""

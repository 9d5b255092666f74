"""The one error of the file formats."""


class SceneError(ValueError):
    """A scene, path or table file that cannot be used; the message names the file and the key,
    row or column, never a cell's text beyond a number."""

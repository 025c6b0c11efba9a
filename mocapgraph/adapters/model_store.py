"""A calibrated model kept by a node: written to its file without raising, and its message form.

Every model file a node reads or writes lies in the folder of its ``model_file`` param, symlinks
followed, and is a regular file (or absent): :func:`model_path`, the rule of
:mod:`mocapgraph.bus.file_places`, so a command from the bus cannot name another place.
The message carries the layout's marker -> limb map only when the model is for that layout
(a model loaded for another layout keeps its own owner limbs).
"""
from __future__ import annotations

from ..bus.file_places import PathRefused, checked_path, named_folders
from ..kinematics.model import ActorModel, save_model
from ..kinematics.skeleton import SkeletonDefinition
from ..messages import SkeletonModel
from .model_messages import model_to_message


def model_path(path: object, model_file: str, what: str = "model file") -> str:
    """``path`` if it names a regular file (or none yet) in ``model_file``'s folder; PathRefused
    (one line) otherwise, also when there is no ``model_file`` to name a folder."""
    if not isinstance(path, str) or not path:
        raise PathRefused(f"{what}: no path given")
    checked_path(path, named_folders([model_file]), what)
    return path


def save_problem(model: ActorModel, path: str, model_file: str) -> str:
    """Write ``model`` to ``path`` (checked by :func:`model_path`); '' when written, else one line saying why not."""
    try:
        save_model(model, model_path(path, model_file))
    except PathRefused as exc:
        return str(exc)
    except OSError as exc:
        return f"cannot write {path}: {exc.strerror or exc}"
    return ""


def model_message(model: ActorModel, definition: SkeletonDefinition | None) -> SkeletonModel:
    """The latched ``skeleton_model`` message of ``model`` (exact; see model_messages)."""
    same = definition is not None and definition.name == model.layout
    return model_to_message(model, definition.marker_limb if same else None)

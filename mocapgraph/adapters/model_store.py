"""A calibrated model kept by a node: written to its file without raising, and its message form.

The message carries the layout's marker -> limb map only when the model is for that layout
(a model loaded for another layout keeps its own owner limbs).
"""
from __future__ import annotations

from ..kinematics.model import ActorModel, save_model
from ..kinematics.skeleton import SkeletonDefinition
from ..messages import SkeletonModel
from .model_messages import model_to_message


def save_problem(model: ActorModel, path: str) -> str:
    """Write ``model`` to ``path``; '' when written, else one line saying why not."""
    try:
        save_model(model, path)
    except OSError as exc:
        return f"cannot write {path}: {exc.strerror or exc}"
    return ""


def model_message(model: ActorModel, definition: SkeletonDefinition | None) -> SkeletonModel:
    """The latched ``skeleton_model`` message of ``model`` (exact; see model_messages)."""
    same = definition is not None and definition.name == model.layout
    return model_to_message(model, definition.marker_limb if same else None)

"""Typed messages, their ZeroMQ codec and JSON schemas. See `types` for the catalogue."""
from .codec import DecodeError, Envelope, decode, decode_envelope, decode_payload, encode, topic_frame
from .registry import UnknownTypeError, all_types, lookup
from .schema import Array, Message, MessageError, Scalar, Strings, array, scalar, strings
from .types import *  # noqa: F401,F403
from .types import (
    QUALITY_ESTIMATED,
    QUALITY_GOOD,
    QUALITY_MISSING,
    ActorPose,
    CharacterInfo,
    CharacterPose,
    Diagnostics,
    ImageLandmarks,
    MarkerFrame,
    MarkerLayout,
    NodeCommand,
    NodeStatus,
    PhysicsScene,
    PhysicsState,
    RigidBodyFrame,
    RigidBodyLayout,
    SkeletonInfo,
    SkeletonModel,
    SkeletonPose,
)

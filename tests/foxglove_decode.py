"""Decoding Foxglove messages with the schema they travel with (protobuf FileDescriptorSet), as
the Foxglove app does: nothing of ours is used to read them back."""
from __future__ import annotations

from google.protobuf import descriptor_pb2, descriptor_pool, message_factory


def message_class(schema_name: str, schema_data: bytes):
    """The protobuf class of ``schema_name`` built from a serialized FileDescriptorSet."""
    fds = descriptor_pb2.FileDescriptorSet.FromString(schema_data)
    pool = descriptor_pool.DescriptorPool()
    for f in fds.file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(schema_name))

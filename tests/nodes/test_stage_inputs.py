"""The visualizer and the Foxglove bridge subscribe to one stage input set, each with its own queue."""
from __future__ import annotations

from mocapgraph.launch.check import load_node_class
from mocapgraph.nodes.foxglove_bridge import QUEUE, FoxgloveBridge
from mocapgraph.nodes.stage_inputs import STAGE_TOPICS
from mocapgraph.nodes.visualizer import FRAME_QUEUE, Visualizer


def _inputs(cls: type) -> dict[str, tuple]:
    """Each declared input as (topic, type, latched, required, queue)."""
    return {name: (p.topic, p.msg_type, p.latched, p.required, p.queue) for name, p in cls.interface({}).inputs.items()}


def test_both_views_declare_every_stage_topic_and_nothing_else() -> None:
    assert len(STAGE_TOPICS) == 13
    for cls, queue in ((Visualizer, FRAME_QUEUE), (FoxgloveBridge, QUEUE)):
        want = {name: (topic, msg_type, latched, False, queue)
                for name, (topic, msg_type, _doc, latched) in STAGE_TOPICS.items()}
        assert _inputs(cls) == want, cls.__name__


def test_the_views_keep_their_own_queue_depths() -> None:
    assert {p[4] for p in _inputs(Visualizer).values()} == {FRAME_QUEUE}
    assert {p[4] for p in _inputs(FoxgloveBridge).values()} == {QUEUE}
    assert FRAME_QUEUE != QUEUE   # the visualizer keeps the newest frame; the bridge buffers for encoding


def test_the_registry_loads_the_views_with_the_shared_inputs() -> None:
    for type_name, cls in (("visualizer", Visualizer), ("foxglove_bridge", FoxgloveBridge)):
        _path, loaded = load_node_class(type_name)
        assert loaded is cls
        assert set(loaded.interface({}).inputs) == set(STAGE_TOPICS)
        assert loaded.markers.topic == "markers"   # a declaration reads as a class attribute, as before

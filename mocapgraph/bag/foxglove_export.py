"""A bag of ours rewritten for Foxglove: the same session as ``foxglove.SceneUpdate`` and JSON plots.

Our bags keep every message byte for byte in our own encoding (``mocapgraph/frames-v1``, for
byte-exact replay); Foxglove opens them but cannot decode them. The export writes a new MCAP
file with Foxglove's well-known schemas instead: per drawn topic a ``/<topic>`` channel of
protobuf ``SceneUpdate`` (schema: the official SDK's FileDescriptorSet), diagnostics as JSON
on ``/diagnostics/<node>``. Message log times are the source's, so the session plays in
Foxglove's 3D panel with its recorded timing. The source bag is only read.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from mcap.writer import CompressionType, Writer

from .errors import BagError
from .foxglove_scene import SceneBuilder, scene_schema
from .reader import BagReader
from .writer import mocapgraph_version


@dataclass
class ExportReport:
    """What an export wrote: messages per Foxglove topic, source messages skipped and why."""

    source: Path
    output: Path
    written: dict[str, int] = field(default_factory=dict)
    skipped: dict[str, int] = field(default_factory=dict)  # source topic -> undecodable messages
    not_drawn: dict[str, str] = field(default_factory=dict)  # source topic -> its type
    stopped: str = ""  # damage that ended the read early

    def text(self) -> str:
        lines = [f"exported {self.source} -> {self.output}"]
        lines += [f"  {t}: {n} messages" for t, n in sorted(self.written.items())]
        if self.not_drawn:
            lines.append("not drawn (no Foxglove form): "
                         + ", ".join(f"{t} ({k})" for t, k in sorted(self.not_drawn.items())))
        if self.skipped:
            lines.append("skipped undecodable: " + ", ".join(f"{t} {n}" for t, n in sorted(self.skipped.items())))
        if self.stopped:
            lines.append(f"stopped early: {self.stopped}")
        return "\n".join(lines)


def export_foxglove(src: str | Path, dst: str | Path, topics: Iterable[str] | None = None,
                    progress: Callable[[int, int], None] | None = None) -> ExportReport:
    """Write ``dst`` (MCAP, Foxglove schemas) from our bag ``src``; BagError for an unusable source."""
    src, dst = Path(src), Path(dst)
    if src.resolve() == dst.resolve():
        raise BagError(dst, "is the source bag; give another output file")
    rep = ExportReport(src, dst)
    builder = SceneBuilder()
    with BagReader(src) as reader:
        infos = reader.topic_infos()
        want = set(infos) if topics is None else set(topics)
        unknown = sorted(want - set(infos))
        if unknown:
            raise BagError(src, f"has no topic {', '.join(map(repr, unknown))} (topics: {', '.join(sorted(infos))})")
        want |= {t for t, i in infos.items() if i.latched}  # names and parents the frames need
        total = sum(infos[t].count for t in want)
        try:
            out = open(dst, "wb")
        except OSError as exc:
            raise BagError(dst, f"cannot write ({exc.strerror or exc})") from None
        with out:
            w = Writer(out, compression=CompressionType.LZ4)
            w.start(profile="", library=f"mocapgraph/{mocapgraph_version()} export-foxglove")
            w.add_metadata("mocapgraph", {"exported_from": src.name, "writer": "bag export-foxglove"})
            name, data = scene_schema()
            scene_id = w.register_schema(name, "protobuf", data)
            json_schemas: dict[str, int] = {}
            channels: dict[str, int] = {}
            seqs: dict[int, int] = {}
            done = 0
            try:
                for raw in reader.messages(sorted(want)):
                    done += 1
                    if progress is not None and done % 512 == 0:
                        progress(done, total)
                    try:
                        env, msg = raw.decode()
                    except BagError:
                        rep.skipped[raw.topic] = rep.skipped.get(raw.topic, 0) + 1
                        continue
                    outs = builder.feed(env, msg, raw.topic)
                    if not outs and not env.latched and not msg.latched_by_default:
                        rep.not_drawn[raw.topic] = env.type_name
                    for m in outs:
                        ch = channels.get(m.topic)
                        if ch is None:
                            if m.encoding == "protobuf":
                                schema = scene_id
                            else:
                                schema = json_schemas.get(m.schema) or json_schemas.setdefault(
                                    m.schema, w.register_schema(m.schema, "jsonschema", m.schema_data))
                            ch = channels[m.topic] = w.register_channel(m.topic, m.encoding, schema,
                                                                        {"source_topic": raw.topic})
                        seqs[ch] = seqs.get(ch, 0) + 1
                        w.add_message(ch, log_time=raw.log_ns, publish_time=raw.publish_ns or raw.log_ns,
                                      data=m.data, sequence=seqs[ch] & 0xFFFFFFFF)
                        rep.written[m.topic] = rep.written.get(m.topic, 0) + 1
            except BagError as exc:
                rep.stopped = f"{exc} (exported what came before; `mocapgraph bag recover` may save more)"
            w.finish()
    if progress is not None:
        progress(total, total)
    return rep

"""``--help`` examples of every command, in one place so that they read as one style.

The style: inputs positional, outputs always ``-o/--output``, options after. `attach` adds each
command's examples to its parser's epilog (a command that wrote its own epilog keeps it and gets
ours below it); a test parses every example with the real parser, so none can go stale.
Commands of parts not merged yet may be listed: an entry without a command is simply unused.
"""
from __future__ import annotations

import argparse

EXAMPLES: dict[str, list[tuple[str, str]]] = {
    "launch": [("graph_configs/demo.yaml", "the demo: synthetic actor, calibration, solver, viewer"),
               ("split.yaml --machine capture", "only the nodes with machine: capture, connected to the others'"),
               ("graph_configs/lab_c3d.yaml capture:=trial.c3d", "a lab graph with an arg overridden")],
    "graph check": [("graph_configs/lab_serial.yaml", "validate without starting anything")],
    "graph show": [("graph_configs/demo.yaml", "the graph as text"),
                   ("graph_configs/demo.yaml --format png -o demo.png", "drawn by Graphviz")],
    "node list": [("", "every node type")],
    "node info": [("lsl_outlet", "ports and params of one type")],
    "topic list": [("-v", "topics of the running graph, with types and publishers")],
    "topic info": [("markers", "type, fields, publishers and subscribers")],
    "topic echo": [("actor_pose -n 3", "three messages"), ("markers --json --timeout 5", "JSON lines for 5 s")],
    "topic hz": [("markers --duration 10", "rate and gaps over 10 s")],
    "bag record": [("--all -o session.mcap", "every topic of the running graph"),
                   ("markers actor_pose --duration 60 -o take1.mcap", "two topics for a minute")],
    "bag play": [("session.mcap", "with the recorded timing"), ("session.mcap -r 0.5 --loop", "half speed, looping")],
    "bag info": [("session.mcap", "duration, topics, rates, gaps"), ("session.mcap --fast --json", "index only")],
    "bag convert": [("trial.c3d -o trial.mcap", "a C3D (or TRC, BVH, Kinect CSV) into a bag"),
                    ("session.mcap -o markers.trc --units mm", "a bag's markers back to TRC")],
    "bag recover": [("crashed.mcap -o saved.mcap", "every whole chunk of a cut bag"),
                    ("crashed.mcap -o saved.mcap --force", "replacing an earlier recovery")],
    "keys generate": [("keys", "keys/graph.key and keys/graph.key_secret for a graph's security: section"),
                      ("keys --name render_pc", "a second pair, e.g. one per machine")],
    "bag export-foxglove": [("session.mcap -o session.foxglove.mcap", "for Foxglove's 3D and Plot panels"),
                            ("session.mcap -o scene.mcap --topics markers actor_pose", "two topics only")],
    "calibrate": [("static.c3d rom.c3d --layout plug_in_gait -o model.json", "static then range of motion"),
                  ("rom.trc --layout kiip_full_body -o model.json --report report.html", "with a report")],
    "solve": [("walk.c3d --model model.json -o walk.csv", "joint centres per frame"),
              ("walk.c3d --model model.json -o walk.mcap", "as a bag to replay or export")],
    "device simulate serial": [("--port pty", "a new pseudo-terminal speaking the wire protocol")],
    "device simulate udp": [("--to 127.0.0.1:9870", "datagrams to a udp_reader")],
    "device simulate lsl": [("--name mocap_sim --rate 240", "an LSL outlet for the lsl_reader")],
    "device simulate qtm": [("--port 22223 --rate 240", "a QTM RT server for the qtm_reader (lab_qtm.yaml)"),
                            ("--restart-every 30 --loss 0.05", "QTM restarting every 30 s, 5 % of frames skipped"),
                            ("--file session.mcap", "a recorded bag's markers instead of the synthetic actor")],
    "device simulate natnet": [("--natnet 4.1 --rate 240", "a Motive NatNet server for lab_natnet.yaml"),
                               ("--natnet 3.0 --loss 0.05 --restart-after 1200", "with 5 % loss and one restart"),
                               ("--file walk.c3d --delay-ms 20 --drift-ppm 100", "a C3D's markers, 0-20 ms late, "
                                                                                "Motive's clock 100 ppm fast")],
    "device replay": [("../shared/data/natnet/traffic.pcapng", "a captured Motive session to a natnet_reader"),
                      ("traffic.pcapng --speed 2 --to 127.0.0.1:1511", "twice as fast, straight to an address"),
                      ("qtm_session.pcapng --port 22223", "a captured QTM RT session (TCP) to a qtm_reader")],
    # parts in other branches (used once they are merged)
    "retarget": [("131_01.bvh --character standard_20 -o out.bvh", "a BVH onto a character"),
                 ("walk.c3d --model model.json --character standard_20 -o out.mcap", "an optical trial")],
    "physics mjcf": [("standard_20 -o body.xml", "the character's MuJoCo body")],
    "posture-db build": [("synthetic:walk,reach -o postures.npz", "from synthetic clips")],
}


def _leaves(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(command path, parser) of every command that runs something."""
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield " ".join(path), parser
        return
    for action in subs:
        for name, p in action.choices.items():
            yield from _leaves(p, path + (name,))


def leaves(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """Command path ("bag convert") -> its parser, for every leaf command."""
    return dict(_leaves(parser))


def attach(parser: argparse.ArgumentParser) -> None:
    """Put each leaf command's examples into its --help (after its own epilog, if any)."""
    for path, p in leaves(parser).items():
        ex = EXAMPLES.get(path)
        if not ex:
            continue
        cmds = [f"mocapgraph {path} {args}".rstrip() for args, _ in ex]
        width = max(map(len, cmds))
        lines = ["examples:"] + [f"  {c:<{width}}  # {what}" for c, (_, what) in zip(cmds, ex)]
        p.epilog = (p.epilog + "\n\n" if p.epilog else "") + "\n".join(lines)
        if p.formatter_class is argparse.HelpFormatter:
            p.formatter_class = argparse.RawDescriptionHelpFormatter

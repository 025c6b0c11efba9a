"""The calibration report: per-joint residual and range-of-motion bars, marker residuals over
time, joint centres on the base pose, as a self-contained HTML page or one PNG (matplotlib).

Numbers come from the model itself (``quality.residual_rms`` in mm, ``range_of_motion`` in
degrees) so that the page says what the model file says; marker residuals are recomputed from
the calibration frames (:func:`~mocapgraph.kinematics.calibration.marker_residuals.marker_residuals`).
Views of the base pose: front (from +X, looking back: Y to the right, Z up) and side (X forward, Z up).
Nothing is fetched from the internet: figures are embedded PNGs.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import base64
import html
import io
import warnings
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from ..kinematics.calibration.marker_residuals import marker_residuals

if TYPE_CHECKING:  # for hints only: nothing of the model module is needed at run time
    from ..kinematics.model import ActorModel

RELIABLE = "#3f7fd9"
UNRELIABLE = "#e8871e"
WORST_MARKERS = 6


def _bars(ax, names: list[str], values: np.ndarray, ok: np.ndarray, ylabel: str, title: str,
          line: float | None = None) -> None:
    x = np.arange(len(names))
    v = np.nan_to_num(values, nan=0.0)
    ax.bar(x, v, color=np.where(ok, RELIABLE, UNRELIABLE))
    ax.set_xticks(x, names, rotation=60, ha="right", fontsize=7)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=10)
    if line is not None:
        ax.axhline(line, color="#c33", lw=1, ls="--", label=f"minimum {line:g}")
        ax.legend(fontsize=7, loc="upper right")
    ax.grid(axis="y", alpha=0.3)


def _residual_plot(ax, labels: list[str], resid_mm: np.ndarray, rate_hz: float | None) -> list[tuple[str, float]]:
    T = resid_mm.shape[0]
    t = np.arange(T) / rate_hz if rate_hz else np.arange(T)
    with warnings.catch_warnings():  # all-NaN frames or markers are expected: no value there
        warnings.simplefilter("ignore", RuntimeWarning)
        med = np.nanmedian(resid_mm, axis=1)
        worst = np.nanmax(resid_mm, axis=1)
        per_marker = np.nanmedian(resid_mm, axis=0)
    ax.fill_between(t, 0, np.nan_to_num(worst), color="#ccc", label="largest marker")
    ax.plot(t, med, color="k", lw=1, label="median marker")
    order = [int(i) for i in np.argsort(-np.nan_to_num(per_marker, nan=-1))[:WORST_MARKERS]]
    for i in order:
        ax.plot(t, resid_mm[:, i], lw=0.7, label=labels[i])
    ax.set_xlabel("time, s" if rate_hz else "frame")
    ax.set_ylabel("residual, mm")
    ax.set_title("marker residuals from the limb fits over the calibration frames", fontsize=10)
    ax.legend(fontsize=6, ncol=4, loc="upper right")
    ax.grid(alpha=0.3)
    return [(labels[i], float(per_marker[i])) for i in order]


def _pose_view(ax, model: ActorModel, u: int, v: int, title: str) -> None:
    m, j = model.base_markers, model.joint_base
    ax.scatter(m[:, u], m[:, v], s=6, color="#999", label="markers")
    par = np.asarray(model.joint_parent)
    for c in np.flatnonzero(par >= 0):
        p = par[c]
        ax.plot([j[p, u], j[c, u]], [j[p, v], j[c, v]], color="#444", lw=1.2)
    ok = np.asarray(model.quality.reliable, bool)
    ax.scatter(j[:, u], j[:, v], s=22, color=np.where(ok, RELIABLE, UNRELIABLE), zorder=3, label="joints")
    for k, name in enumerate(model.joint_names):
        ax.annotate(name, (j[k, u], j[k, v]), fontsize=5, xytext=(3, 2), textcoords="offset points")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel("XYZ"[u] + ", m")
    ax.set_ylabel("XYZ"[v] + ", m")
    ax.grid(alpha=0.3)


def _png(fig: Figure) -> bytes:
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    return buf.getvalue()


SIZES = {"joints": 3.4, "markers": 3.2, "pose": 5.0}  # figure heights, inches (10 wide)


def _draw(fig, key: str, model: ActorModel, resid_mm: np.ndarray | None,
          min_rom_deg: float | None) -> list[tuple[str, float]]:
    """Draw panel group ``key`` into a Figure or SubFigure; the worst markers for "markers"."""
    names = list(model.joint_names)
    q = model.quality
    ok = np.asarray(q.reliable, bool)
    if key == "joints":
        a, b = fig.subplots(1, 2)
        _bars(a, names, q.residual_rms * 1000, ok, "residual RMS, mm", "per-joint residual (blue reliable, orange not)")
        _bars(b, names, np.degrees(q.range_of_motion), ok, "range of motion, deg", "per-joint range of motion",
              min_rom_deg)
    elif key == "markers":
        return _residual_plot(fig.subplots(), list(model.marker_labels), resid_mm, model.rate_hz)
    else:
        a, b = fig.subplots(1, 2)
        _pose_view(a, model, 1, 2, "base pose, front (from +X: its left on your right)")
        _pose_view(b, model, 0, 2, "base pose, side (from -Y)")
    return []


def write_report(path: str | Path, model: ActorModel, markers: np.ndarray | None = None,
                 source: str = "", model_path: str = "", min_rom_deg: float | None = None) -> Path:
    """Write the report as ``.html`` (page with table and figures) or ``.png`` (the figures stacked).

    markers: the calibration frames float[T,M,3] in the model's marker order (for residuals over time).
    """
    path = Path(path)
    resid = marker_residuals(model, markers) * 1000 if markers is not None and len(markers) else None
    keys = [k for k in ("joints", "markers", "pose") if k != "markers" or resid is not None]
    worst: list[tuple[str, float]] = []
    if path.suffix.lower() == ".png":
        heights = [SIZES[k] for k in keys]
        big = Figure(figsize=(10, sum(heights) + 0.4), layout="constrained")
        big.suptitle(f"calibration of {model.layout} ({source or 'capture'})", fontsize=11)
        for sub, k in zip(np.atleast_1d(big.subfigures(len(keys), 1, height_ratios=heights)), keys):
            _draw(sub, k, model, resid, min_rom_deg)
        path.write_bytes(_png(big))
        return path
    pngs = {}
    for k in keys:
        f = Figure(figsize=(10, SIZES[k]), layout="constrained")
        worst = _draw(f, k, model, resid, min_rom_deg) or worst
        pngs[k] = _png(f)
    path.write_text(_html(model, pngs, worst, source, model_path, min_rom_deg))
    return path


def _fmt(v: float, nd: int) -> str:
    return "-" if not np.isfinite(v) else f"{v:.{nd}f}"


def _html(model: ActorModel, pngs: dict[str, bytes], worst: list[tuple[str, float]], source: str,
          model_path: str, min_rom_deg: float | None) -> str:
    e = html.escape
    q = model.quality
    rows = []
    for j, name in enumerate(model.joint_names):
        rel = bool(q.reliable[j])
        rows.append(
            f'<tr class="{"ok" if rel else "bad"}"><td class="joint">{e(name)}</td>'
            f'<td class="method">{e(q.method[j])}{" (points)" if q.from_points[j] else ""}</td>'
            f'<td class="residual_mm">{_fmt(q.residual_rms[j] * 1000, 2)}</td>'
            f'<td class="se_mm">{_fmt(q.centre_se[j] * 1000, 2)}</td>'
            f'<td class="rom_deg">{_fmt(np.degrees(q.range_of_motion[j]), 1)}</td>'
            f'<td class="frames">{int(q.n_frames[j])}</td>'
            f'<td class="bone_mm">{_fmt(model.bone_length[j] * 1000, 1)}</td>'
            f'<td class="reliable">{"yes" if rel else "NO"}</td></tr>')
    img = {k: base64.b64encode(v).decode() for k, v in pngs.items()}
    figures = "".join(f'<figure id="fig-{k}"><img alt="{k}" src="data:image/png;base64,{v}"></figure>'
                      for k, v in img.items())
    warn = "".join(f"<li>{e(w)}</li>" for w in model.warnings) or "<li>none</li>"
    worst_rows = "".join(f'<tr><td>{e(n)}</td><td class="median_mm">{_fmt(v, 2)}</td></tr>' for n, v in worst)
    rate = f"{model.rate_hz:g} Hz" if model.rate_hz else "unknown rate"
    n_ok = int(np.sum(q.reliable))
    return f"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>calibration report: {e(model.layout)}</title>
<style>
body {{ font: 14px system-ui, sans-serif; margin: 1.5em auto; max-width: 1120px; color: #222; }}
table {{ border-collapse: collapse; margin: 0.5em 0 1.5em; }}
td, th {{ border-bottom: 1px solid #ddd; padding: 2px 10px; text-align: right; }}
td.joint, td.method, th.l {{ text-align: left; }}
tr.bad td {{ background: #fff1e0; }}
figure {{ margin: 0.5em 0; }} img {{ max-width: 100%; }}
.summary span {{ margin-right: 2em; }}
</style></head><body>
<h1>Calibration report</h1>
<p class="summary"><span>layout <b id="layout">{e(model.layout)}</b></span>
<span>source {e(source or "?")}</span><span>model {e(model_path or "?")}</span>
<span><b id="gym-frames">{model.n_gym_frames}</b> gym frames at {rate}</span>
<span><b id="reliable-count">{n_ok}</b> of {len(model.joint_names)} joints reliable</span></p>
<h2>Joints</h2>
<p>Residual: RMS disagreement between the centres seen from the joint's two limbs over the gym
frames, mm. +-SE: the centre's standard error from the marker noise the clusters' own residuals
show ({_fmt(model.marker_noise * 1000, 2)} mm), mm{f"; reliable up to {model.max_uncertainty * 1000:g}"
if np.isfinite(model.max_uncertainty) else ""}; "(points)": found from a limb's markers as points,
its cluster unable to fix its own orientation. Range of motion: largest rotation between the two
limbs, degrees {f"(reliable from {min_rom_deg:g})" if min_rom_deg is not None else ""}.</p>
<table id="joints"><thead><tr><th class="l">joint</th><th class="l">method</th><th>residual mm</th>
<th>+-SE mm</th><th>ROM deg</th><th>frames</th><th>bone mm</th><th>reliable</th></tr></thead>
<tbody>{"".join(rows)}</tbody></table>
<h2>Warnings</h2><ul id="warnings">{warn}</ul>
{figures}
<h2>Markers with the largest residuals</h2>
<table id="worst-markers"><thead><tr><th class="l">marker</th><th>median mm</th></tr></thead>
<tbody>{worst_rows}</tbody></table>
</body></html>
"""

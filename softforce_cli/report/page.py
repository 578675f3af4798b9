"""One self-contained HTML page: plotly's JavaScript inline, PNGs as data URIs, nothing
fetched, so the file opens offline and can be mailed as it is."""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import plotly.graph_objects as go
from plotly.offline import get_plotlyjs

from softforce_cli.report.charts import Chart
from softforce_cli.report.scene import ContactScene

STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: .2em; }
table { border-collapse: collapse; margin: .5em 0 1em; }
td, th { border: 1px solid #ccc; padding: .25em .6em; text-align: right; }
th { background: #f3f3f3; } td:first-child, th:first-child { text-align: left; }
.note { color: #8a5a00; } .figure { margin: 1em 0; } img { max-width: 100%; }
"""


@dataclass(frozen=True)
class Section:
    title: str
    body: str


def chart_div(chart: Chart) -> str:
    figure = go.Figure()
    for trace in chart.traces:
        if trace.kind == "bar":
            figure.add_bar(x=_list(trace.x), y=_list(trace.y), name=trace.name)
        else:
            mode = "markers" if trace.kind == "markers" else "lines+markers"
            figure.add_scatter(x=_list(trace.x), y=_list(trace.y), mode=mode, name=trace.name)
    if chart.reference is not None:
        value, label = chart.reference
        figure.add_hline(y=value, line_dash="dash", annotation_text=label)
    if chart.diagonal:
        top = max((float(np.nanmax(np.r_[t.x, t.y], initial=0.0)) for t in chart.traces),
                  default=1.0) * 1.05
        figure.add_scatter(x=[0, top], y=[0, top], mode="lines", name="estimated = true",
                           line={"dash": "dot", "color": "grey"})
    figure.update_layout(title=chart.title, xaxis_title=chart.x_label,
                         yaxis_title=chart.y_label, height=420, template="plotly_white",
                         barmode="stack" if chart.stacked else "group")
    return _div(figure, chart.key)


def scene_div(scene: ContactScene, key: str) -> str:
    """The robot's surface (mesh), contacts coloured by force, force arrows ending at them."""
    nodes, faces = scene.shape.positions_mm, scene.shape.surface_faces
    figure = go.Figure(go.Mesh3d(
        x=_list(nodes[:, 0]), y=_list(nodes[:, 1]), z=_list(nodes[:, 2]),
        i=faces[:, 0].tolist(), j=faces[:, 1].tolist(), k=faces[:, 2].tolist(),
        color="#7fa3d9", opacity=0.45, name="robot", hoverinfo="skip", flatshading=True))
    if len(scene.nodes):
        located = nodes[scene.nodes]
        figure.add_scatter3d(x=_list(located[:, 0]), y=_list(located[:, 1]),
                             z=_list(located[:, 2]), mode="markers", name="located nodes",
                             marker={"size": 4, "color": "crimson"})
    if len(scene.points_mm):
        points = scene.points_mm
        tails = points - scene.arrow_mm_per_n * scene.forces_n
        segments = np.full((3 * len(points), 3), np.nan)
        segments[0::3], segments[1::3] = tails, points
        figure.add_scatter3d(x=_list(segments[:, 0]), y=_list(segments[:, 1]),
                             z=_list(segments[:, 2]), mode="lines", name="force (pushing)",
                             line={"color": "black", "width": 5}, hoverinfo="skip")
        figure.add_scatter3d(
            x=_list(points[:, 0]), y=_list(points[:, 1]), z=_list(points[:, 2]),
            mode="markers", name="contacts", text=list(scene.labels), hoverinfo="text",
            marker={"size": 5, "color": _list(scene.magnitudes_n), "colorscale": "Viridis",
                    "colorbar": {"title": "force (N)"}})
    figure.update_layout(title=scene.title, height=620, template="plotly_white",
                         legend={"x": 0.0, "y": 0.95},
                         scene={"aspectmode": "data", "xaxis_title": "x (mm)",
                                "yaxis_title": "y (mm)", "zaxis_title": "z (mm)"})
    return _div(figure, key)


def image_tag(png: Path, caption: str) -> str:
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    return (f'<div class="figure"><img alt="{html.escape(caption)}" '
            f'src="data:image/png;base64,{data}"><br><small>{html.escape(caption)}</small></div>')


def table_html(header: Sequence[str] | None, rows: Sequence[Sequence[object]]) -> str:
    """A table; header None for a two-column list of names and values."""
    head = "" if header is None else "<tr>" + "".join(
        f"<th>{html.escape(str(h))}</th>" for h in header) + "</tr>"
    body = "".join("<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>"
                   for row in rows)
    return f"<table>{head}{body}</table>"


def paragraph(text: str, css: str = "") -> str:
    attribute = f' class="{css}"' if css else ""
    return f"<p{attribute}>{html.escape(text)}</p>"


def page_html(title: str, sections: Sequence[Section]) -> str:
    parts = [f"<h2>{html.escape(s.title)}</h2>\n{s.body}" for s in sections]
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>{html.escape(title)}</title><style>{STYLE}</style>"
            f"<script type=\"text/javascript\">{get_plotlyjs()}</script></head>\n<body>"
            f"<h1>{html.escape(title)}</h1>\n" + "\n".join(parts) + "\n</body></html>\n")


def _div(figure: go.Figure, key: str) -> str:
    return figure.to_html(full_html=False, include_plotlyjs=False, div_id=f"figure-{key}",
                          config={"displaylogo": False})


def _list(values: np.ndarray) -> list:
    """Plain floats (None for NaN) for plotly's JSON: no binary arrays, readable anywhere."""
    array = np.asarray(values)
    if array.dtype.kind in "US":
        return array.tolist()
    return [None if not np.isfinite(v) else float(v) for v in array.astype(float)]

"""The bench report: bench.json (every number), summary.md, index.html and the plots.

The JSON is the source of truth: `write_report` draws the plots and writes the HTML and markdown
from it alone, so `bcfpipe bench --redraw REPORT_DIR` can redo them without measuring again.
Non-finite numbers are written as null (JSON has no Infinity).
"""
from __future__ import annotations

import html
import json
import math
from pathlib import Path

from bcfpipe.bench import plots as P
from bcfpipe.errors import InputError
from bcfpipe.formats.atomic import atomic_write

__all__ = ["write_report", "read_report", "summary_markdown", "JSON_FILE", "HTML_FILE", "MD_FILE"]

JSON_FILE = "bench.json"
HTML_FILE = "index.html"
MD_FILE = "summary.md"


def _clean(x):
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    if isinstance(x, dict):
        return {k: _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    return x


def read_report(where: str | Path) -> dict:
    """A bench report's data, from its folder or its bench.json."""
    p = Path(where)
    p = p / JSON_FILE if p.is_dir() else p
    try:
        data = json.loads(p.read_text())
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read {p}: {e}") from None
    if not isinstance(data, dict) or data.get("format") != "bcfpipe-bench":
        raise InputError(f"{p} is not a bcfpipe bench report")
    return data


def _f(v, fmt: str = ".2f") -> str:
    return "-" if v is None else format(v, fmt)


def _rows(s: dict) -> list[dict]:
    return sorted([*s["cells"], *s["baselines"]], key=lambda r: r["size_bytes"])


def _decode_ratio(s: dict, method: str) -> float | None:
    for r in (s.get("decode_cost") or {}).get("rows", []):
        if r["method"] == method:
            return r["ratio"]
    return None


def _mib(r: dict, key: str) -> str:
    v = r.get(key)
    return "-" if v is None else format(v / 2**20, ".3f")


def _against(s: dict) -> list[tuple[dict, dict]]:
    """(BCf cell, reference) for each cell against BC@R and the BC7 quality set at R, R its T_0
    side; those the report holds."""
    out = []
    for c in s["cells"]:
        r = (c.get("resolutions") or [max(s["width"], s["height"])])[0]
        out += [(c, b) for kind in ("bc", "bc7") for b in s["baselines"] if b["kind"] == kind and b["resolution"] == r]
    return out


def _ratio(a, b) -> str:
    return "-" if a is None or not b else f"{a / b:.2f}"


def _margin_rows(s: dict) -> list[list[str]]:
    """Per BCf cell and reference: the size ratios (GPU, disk) and the per-mip margins (dB)."""
    out = []
    for c, b in _against(s):
        margins = [x - y if x is not None and y is not None else None
                   for x, y in zip(c["psnr_per_mip"], b["psnr_per_mip"])]
        out.append([c["method"], b["method"], _ratio(c["size_bytes"], b["size_bytes"]),
                    _ratio(c.get("disk_bytes"), b.get("disk_bytes")), *[_f(v, "+.1f") for v in margins]])
    return out


def _margins_markdown(s: dict) -> list[str]:
    rows = _margin_rows(s)
    if not rows:
        return []
    head = ["method", "against", "GPU bytes ×", "disk bytes ×", *[f"mip {k}" for k in range(len(s["mips"]))]]
    return ["\nAgainst BC@R and the BC7 quality set at R, R each BCf cell's T_0 side: size ratios and per-mip "
            "PSNR margins (dB, + where BCf is better):\n", "| " + " | ".join(head) + " |\n|---|---|" + "---:|" * (len(head) - 2),
            *("| " + " | ".join(r) + " |" for r in rows)]


def summary_markdown(data: dict) -> str:
    m = data["machine"]
    out = [f"# bcfpipe bench\n\nMachine: {m['cpu']}, {m['cores']} cores, torch {m['torch']}, "
           f"{m['gpu'] or 'no GPU'}. bcfpipe {data['bcfpipe_version']}.\n"]
    for s in data["sets"]:
        n = len(s["mips"])
        out.append(f"\n## {s['name']} ({s['width']}x{s['height']}, {len(s['channels'])} channels)\n\n"
                   f"Sources: {', '.join(f'`{x}`' for x in s['sources'])}\n")
        head = ["method", "GPU MiB", "disk MiB", "PSNR all mips", *[f"mip {k}" for k in range(n)], "SSIM", "FLIP",
                "time (s)", "decode / BC"]
        out.append("| " + " | ".join(head) + " |\n|" + "---|" + "---:|" * (len(head) - 1))
        for r in _rows(s):
            t = r.get("train_seconds", r["seconds"])
            cells = [r["method"], _f(r["size_mib"], ".3f"), _mib(r, "disk_bytes"), _f(r["psnr"]), *[_f(v, ".1f") for v in r["psnr_per_mip"]],
                     _f(r["ssim"], ".4f"), _f(r["flip"], ".4f"), _f(t, ".0f"),
                     _f(_decode_ratio(s, r["method"]), ".1f") if r["kind"] == "bcf" else "-"]
            out.append("| " + " | ".join(cells) + " |")
        out.extend(_margins_markdown(s))
        groups = sorted({g for r in s["cells"] for g in r["psnr_per_group"]})
        if groups:
            out.append("\nPSNR per channel group (all mips, dB):\n\n| method | " + " | ".join(groups) + " |\n|---|"
                       + "---:|" * len(groups))
            for r in _rows(s):
                out.append(f"| {r['method']} | " + " | ".join(_f(r["psnr_per_group"].get(g)) for g in groups) + " |")
        angled = [r for r in _rows(s) if r.get("normal_angle_deg")]
        if angled:  # beside the PSNR, which measures x and y only (issue 57)
            out.append("\nNormal map's angle at mip 0, z rebuilt from x, y (degrees):\n\n| method | mean | p99 |\n"
                       "|---|---:|---:|")
            for r in angled:
                a = r["normal_angle_deg"]
                out.append(f"| {r['method']} | {a['mean']:.2f} | {a['p99']:.2f} |")
                if r.get("normal_angle_deg_shipped"):  # what a layout ships for USD (BC5 slopes)
                    a = r["normal_angle_deg_shipped"]
                    out.append(f"| {r['method']}, BC5 slopes as USD reads them (shipped) | {a['mean']:.2f} | "
                               f"{a['p99']:.2f} |")
        d = s.get("decode_cost") or {}
        if d.get("rows"):
            out.append(f"\nDecode cost at {d['width']}x{d['height']}, {d['renderer']} ({d['timer']}, median of "
                       f"{d['frames']} interleaved frames), neural against {d['classic']} "
                       f"({', '.join(d['classic_formats'])}): {d['note']}.")
        elif d.get("skipped"):
            out.append(f"\nDecode cost: not measured ({d['skipped']}).")
    return "\n".join(out) + "\n"


def _table_html(s: dict) -> str:
    n = len(s["mips"])
    head = ["method", "GPU MiB", "disk MiB", "PSNR all mips", *[f"mip {k}" for k in range(n)], "SSIM mip 0",
            "FLIP mip 0", "time (s)", "decode / BC"]
    rows = []
    for r in _rows(s):
        t = r.get("train_seconds", r["seconds"])
        vals = [_f(r["size_mib"], ".3f"), _mib(r, "disk_bytes"), _f(r["psnr"]), *[_f(v, ".1f") for v in r["psnr_per_mip"]],
                _f(r["ssim"], ".4f"), _f(r["flip"], ".4f"), _f(t, ".0f"),
                _f(_decode_ratio(s, r["method"]), ".1f") if r["kind"] == "bcf" else "-"]
        cls = ' class="bcf"' if r["kind"] == "bcf" else ""
        rows.append(f"<tr{cls}><td>{html.escape(r['method'])}</td>" + "".join(f"<td>{v}</td>" for v in vals) + "</tr>")
    return ("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>" + "".join(rows)
            + "</table>" + _margins_html(s))


def _margins_html(s: dict) -> str:
    rows = _margin_rows(s)
    if not rows:
        return ""
    head = ["method", "against", "GPU bytes ×", "disk bytes ×", *[f"mip {k}" for k in range(len(s["mips"]))]]
    return ("<p class='note'>Against BC@R and the BC7 quality set at R, R each BCf cell's T_0 side: size ratios "
            "and per-mip PSNR margins (dB, + where BCf is better).</p><table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head)
            + "</tr>" + "".join("<tr>" + "".join(f"<td>{html.escape(v)}</td>" for v in r) + "</tr>" for r in rows)
            + "</table>")


def _html(data: dict, plots: dict[str, dict[str, str]]) -> str:
    m = data["machine"]
    parts = ["<!doctype html><html><head><meta charset='utf-8'><title>bcfpipe bench</title><style>",
             "body{font-family:sans-serif;max-width:1200px;margin:2em auto;padding:0 1em;color:#222}",
             "table{border-collapse:collapse;font-size:12px;margin:1em 0}td,th{border:1px solid #ccc;"
             "padding:2px 6px;text-align:right}td:first-child{text-align:left}tr.bcf{background:#eef5ff}",
             "img{max-width:100%;border:1px solid #ddd;margin:0.5em 0}.note{color:#555;font-size:13px}",
             "</style></head><body><h1>bcfpipe bench</h1>",
             f"<p class='note'>Machine: {html.escape(str(m['cpu']))}, {m['cores']} cores, torch "
             f"{html.escape(m['torch'])}, {html.escape(m['gpu'] or 'no GPU')}. bcfpipe "
             f"{html.escape(data['bcfpipe_version'])}. Every PSNR is measured with the same metric code "
             "against the same reference mips: BCf from its exported files (BC6H DDS + fp16 decoder through "
             "onnxruntime), baselines after encoding and decoding every mip (BC: quicktex, BC1 at its slowest "
             "level for colour and packed maps, BC5 for normal xy, BC4 for a lone scalar; ASTC: astcenc "
             "-thorough, LDR linear; the BC7 quality set: BC with every BC1 texture in BC7, ISPC; a half-size "
             "baseline is magnified bilinearly for the mip it lacks). Sizes are GPU bytes (BCf: its shipped "
             "files; baselines: their blocks) and bytes on disk, each file zstd-compressed at level 19. "
             "PSNR over all mips averages the "
             "MSE of the mips of at least 4x4; SSIM and FLIP are at mip 0.</p>"]
    for s in data["sets"]:
        parts.append(f"<h2 id='{html.escape(s['slug'])}'>{html.escape(s['name'])}</h2><p class='note'>"
                     f"{s['width']}x{s['height']}, {len(s['channels'])} channels: "
                     f"{html.escape(', '.join(s['sources']))}</p>")
        parts.append(_table_html(s))
        d = s.get("decode_cost") or {}
        if d.get("rows"):
            parts.append(f"<p class='note'>Decode cost: a {d['width']}x{d['height']} full-screen pass decoding "
                         f"the neural material against one sampling {html.escape(d['classic'])} "
                         f"({html.escape(', '.join(d['classic_formats']))}), {d['frames']} interleaved frames, "
                         f"{html.escape(d['timer'])} on {html.escape(d['renderer'])}: "
                         f"<b>{html.escape(d['note'])}</b>.</p>")
            if not d["software"]:
                parts.append("<table><tr><th>method</th><th>neural ms</th><th>BC ms</th><th>ratio</th></tr>" + "".join(
                    f"<tr><td>{html.escape(r['method'])}</td><td>{r['neural_ms']:.3f}</td><td>{r['classic_ms']:.3f}"
                    f"</td><td>{r['ratio']:.2f}</td></tr>" for r in d["rows"]) + "</table>")
        elif d.get("skipped"):
            parts.append(f"<p class='note'>Decode cost not measured: {html.escape(d['skipped'])}.</p>")
        for name, f in plots[s["slug"]].items():
            parts.append(f"<h3>{html.escape(P.TITLES[name])}</h3><img src='{html.escape(f)}' "
                         f"alt='{html.escape(s['name'])}: {html.escape(P.TITLES[name])}'>")
        for c in s["crops"]:
            parts.append(f"<h3>Crop at mip {c['mip']}</h3><p class='note'>{c['size']}x{c['size']} at ({c['x']}, "
                         f"{c['y']}), the window with the most detail: "
                         + html.escape(", ".join(f"{k} {v:.2f} dB" for k, v in c["psnr"].items() if v is not None))
                         + f"</p><img src='{html.escape(c['png'])}' alt='crop at mip {c['mip']}'>")
    parts.append("</body></html>\n")
    return "\n".join(parts)


def write_report(data: dict, out: str | Path) -> list[str]:
    """Write bench.json, the plots, summary.md and index.html into ``out``; the file names."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    data = _clean(data)
    atomic_write(out / JSON_FILE, (json.dumps(data, indent=1) + "\n").encode())
    plots = {s["slug"]: P.draw_set(s, out) for s in data["sets"]}
    atomic_write(out / MD_FILE, (summary_markdown(data)).encode())
    atomic_write(out / HTML_FILE, (_html(data, plots)).encode())
    files = [JSON_FILE, MD_FILE, HTML_FILE, *(f for p in plots.values() for f in p.values()),
             *(c["png"] for s in data["sets"] for c in s["crops"])]
    return files

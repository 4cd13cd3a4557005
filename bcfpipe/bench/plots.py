"""The bench's plots, drawn from its JSON alone (so a report can be redrawn without re-measuring).

Per texture set: rate-distortion (PSNR over MiB), PSNR over training time, PSNR per mip and PSNR
over a continuous lod sweep. BCf cells are solid markers, BC dashed, the BC7 quality set dash-dotted,
ASTC dotted; half-resolution baselines are lighter.
"""
from __future__ import annotations

from pathlib import Path

from bcfpipe.extras import require

__all__ = ["PLOTS", "draw_set"]

PLOTS = ("rd", "time", "per_mip", "lod")
SIDE_LEGEND = {"fontsize": 6, "ncol": 2, "loc": "upper left", "bbox_to_anchor": (1.01, 1.0)}
SERIES = {"bc": ("BC", "tab:gray"), "bc7": ("BC7 quality", "tab:purple"), "astc": ("ASTC 4x4..12x12", "tab:green")}
TITLES = {"rd": "Rate-distortion", "time": "PSNR over training time", "per_mip": "PSNR per mip",
          "lod": "PSNR over lod"}


def _plt():
    require("matplotlib", "bench", "bcfpipe bench's figures").use("Agg")
    import matplotlib.pyplot as plt  # lazy: start-up

    return plt


def _style(row: dict, full: int) -> dict:
    half = row.get("resolution", full) < full
    if row["kind"] == "bcf":
        return {"ls": "-", "marker": "o", "alpha": 1.0}
    ls, marker = {"bc": ("--", "s"), "bc7": ("-.", "D")}.get(row["kind"], (":", "^"))
    return {"ls": ls, "marker": marker, "alpha": 0.45 if half else 0.9}


def _finite(v) -> float | None:
    return v if v is not None and v == v and abs(v) != float("inf") else None


def _label(ax, xlabel: str, ylabel: str, title: str, title_size: float | None = None) -> None:
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title, fontsize=title_size)


def _save(plt, fig, ax, path: Path, legend: dict, grid: str = "major") -> None:
    """Grid and legend, then the figure written to ``path`` and closed."""
    ax.grid(alpha=0.3, which=grid)
    ax.legend(**legend)
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)


def draw_rd(s: dict, path: Path) -> None:
    plt = _plt()
    full = max(s["width"], s["height"])
    fig, ax = plt.subplots(figsize=(8.5, 4.4), dpi=110)
    series: dict[tuple, list[dict]] = {}
    for b in s["baselines"]:
        series.setdefault((b["codec"], b["resolution"]), []).append(b)
    for (codec, res), rows in sorted(series.items(), key=lambda kv: (kv[0][0], -kv[0][1])):
        rows = sorted(rows, key=lambda r: r["size_mib"])
        st = _style(rows[0], full)
        name, color = SERIES.get(codec, SERIES["astc"])
        ax.plot([r["size_mib"] for r in rows], [r["psnr"] for r in rows], color=color, label=f"{name} @{res}", **st)
        for r in rows:
            if r["codec"] == "astc":
                ax.annotate(r["block"], (r["size_mib"], r["psnr"]), fontsize=6, xytext=(3, -8),
                            textcoords="offset points", alpha=st["alpha"])
    profiles: dict[str, list[dict]] = {}
    for c in s["cells"]:
        profiles.setdefault(c["profile"], []).append(c)
    for prof, rows in profiles.items():
        for c in rows:
            ax.plot([c["size_mib"]], [c["psnr"]], "o", ms=7, label=f"BCf {prof} {c['preset']}")
    ax.set_xscale("log")
    _label(ax, "GPU size (MiB, log scale; BCf: its feature textures + fp16 weights)", "PSNR over all mips (dB)",
           f"{s['name']}: rate-distortion")
    _save(plt, fig, ax, path, {**SIDE_LEGEND, "ncol": 1, "fontsize": 7}, grid="both")


def draw_time(s: dict, path: Path) -> None:
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7, 4.2), dpi=110)
    for c in s["cells"]:
        curve = c.get("training_curve") or []
        line = ax.plot([t for t, _ in curve], [p for _, p in curve], lw=1, alpha=0.6)[0]
        ax.plot([c["train_seconds"]], [c["psnr"]], "o", ms=7, color=line.get_color(),
                label=f"{c['method']}: {c['psnr']:.2f} dB exported")
    _label(ax, "training wall time (s)", "PSNR (dB)", f"{s['name']}: PSNR over training time\n(lines: training "
           f"loss as PSNR, float model; dots: exported files, all mips)", title_size=9)
    _save(plt, fig, ax, path, {"fontsize": 7, "loc": "lower right"})


def draw_per_mip(s: dict, path: Path) -> None:
    plt = _plt()
    full = max(s["width"], s["height"])
    fig, ax = plt.subplots(figsize=(8, 4.6), dpi=110)
    for row in [*s["baselines"], *s["cells"]]:
        p = [_finite(v) for v in row["psnr_per_mip"]]
        ax.plot(range(len(p)), [v if v is not None else float("nan") for v in p], ms=3, lw=1.4 if row["kind"] == "bcf"
                else 1, label=row["method"], **_style(row, full))
    ax.set_xticks(range(len(s["mips"])))
    ax.set_xticklabels([f"{k}\n{w}" for k, (w, _) in enumerate(s["mips"])], fontsize=7)
    _label(ax, "mip (its width)", "PSNR (dB)", f"{s['name']}: PSNR per mip (exported files; baselines decode every mip)")
    _save(plt, fig, ax, path, SIDE_LEGEND)


def draw_lod(s: dict, path: Path) -> None:
    plt = _plt()
    full = max(s["width"], s["height"])
    sweep = s["lod_sweep"]
    fig, ax = plt.subplots(figsize=(8, 4.6), dpi=110)
    tri = [(x, y) for x, y in zip(sweep["s"], sweep["trilinear_reference"]) if _finite(y) is not None and y < 100]
    ax.plot([x for x, _ in tri], [y for _, y in tri], color="black", lw=1.6, label="trilinear of the reference")
    for row in [*[b for b in s["baselines"] if b.get("resolution") == full], *s["cells"]]:
        ys = [y if _finite(y) is not None and y < 100 else float("nan") for y in row["lod_sweep"]]
        st = _style(row, full)
        ax.plot(sweep["s"], ys, lw=1.2 if row["kind"] == "bcf" else 0.9, ls=st["ls"], alpha=st["alpha"],
                label=row["method"])
    _label(ax, "lod s (reference mip units)", "PSNR (dB)", f"{s['name']}: PSNR over a continuous lod sweep\n"
           f"({sweep['points']} random uv; target: bicubic in mips floor(s), floor(s)+1, lerped)", title_size=9)
    _save(plt, fig, ax, path, SIDE_LEGEND)


DRAW = {"rd": draw_rd, "time": draw_time, "per_mip": draw_per_mip, "lod": draw_lod}


def draw_set(s: dict, out: Path) -> dict[str, str]:
    """Draw every plot of set ``s`` into ``out``; {plot: file name}."""
    files = {}
    for name in PLOTS:
        if name == "time" and not s["cells"]:
            continue
        f = f"{s['slug']}_{name}.png"
        DRAW[name](s, out / f)
        files[name] = f
    return files

"""Option groups shared by several commands, so `bcfpipe train` and `bcfpipe build` cannot drift:
one definition per option, defaults from `bcfpipe.config`."""
from __future__ import annotations

import click
from click.core import ParameterSource

from dataclasses import fields

from bcfpipe.bench.report import read_report
from bcfpipe.errors import InputError
from bcfpipe.formats.vocabulary import T0, FeatureFormat, Kernel, Layout
from bcfpipe.config import (DEFAULT_DEVICE, DEFAULT_PCA_CLIP, DEFAULT_HIDDEN, DEFAULT_INIT, DEFAULT_PRESET, DEFAULT_PROFILE,
                            DEFAULT_SEED, DEFAULT_THREADS, DEFAULT_FEATURES, DEFAULT_KERNEL, FEATURE_INITS, MAX_T0_LAYERS, PRESETS,
                            PROFILE_NAMES, TrainingOptions)

# The training options, in --help order: one per field of config.TrainingOptions, named as it (a
# test checks); `train`, `plan` and `build` take exactly these.
TRAINING_OPTIONS = (
    click.option("--profile", type=click.Choice(PROFILE_NAMES), default=DEFAULT_PROFILE, show_default=True,
                 help="Feature resolutions (paper Table 1, plus 1k++); auto = the largest of 0.5k/1k/2k not "
                      "above the source textures."),
    click.option("--quality", "--preset", "preset", type=click.Choice(list(PRESETS)), default=DEFAULT_PRESET,
                 show_default=True, help="Training preset (steps, batch, learning rates): draft is the fastest worth "
                                         "looking at; smoke only checks a pipeline end to end (the "
                                         "fewest steps; reading, T_0's encode, export and measuring remain: about "
                                         "a minute for a 2048² set on 2 CPU cores); 'paper' is the paper's 206k-step schedule (for a GPU). On a "
                                         "CPU, standard takes fewer steps at a 2048² T_0 (docs/training.md)."),
    click.option("--hidden", type=click.IntRange(min=1), default=DEFAULT_HIDDEN, show_default=True,
                 help="Hidden units of the decoder MLP."),
    click.option("--features", type=click.Choice([f.value for f in FeatureFormat]), default=DEFAULT_FEATURES.value,
                 show_default=True,
                 help="Feature texture format: bc7 (4 channels per layer, 16 MLP inputs; T_0 holds the set's principal "
                      "components in any BC7 mode, see --t0; trained layers are mode 6) or bc6h (the paper's: BC6H "
                      "mode 11110, 3 channels per layer, the same bytes). bc7 measured better on every set "
                      "(docs/training.md)."),
    click.option("--t0", "t0", type=click.Choice([v.value for v in T0]), default=None,
                 help="What the finest feature layer T_0 holds: 'pca' (the default with bc7) the texture set's "
                      "principal components, BC7-encoded once in every mode and kept while the other layers and "
                      "the MLP train around them (sharper close-ups); 'trained' (bc6h's, and the paper's) features "
                      "trained like the others."),
    click.option("--t0-layers", "t0_layers", type=click.IntRange(min=1, max=MAX_T0_LAYERS), default=None,
                 metavar="N",
                 help="BC7 layers of principal components in T_0 (--t0 pca): N holds 4N components, each layer "
                      "T_0's bytes again, with 4 more decoder inputs; capped at the set's channels. Not given: "
                      "--layout auto weighs every width that can help, --layout neural trains 1."),
    click.option("--pca-clip", "pca_clip", type=click.FloatRange(min=0, max=50, max_open=True),
                 default=DEFAULT_PCA_CLIP, show_default=True, metavar="PERCENT",
                 help="Where principal components start the features (--t0 pca, --init pca): the percentage of "
                      "texels at each end of a component's range left outside the feature range (clipped). 0 "
                      "keeps every texel's value, at a coarser step for all of them."),
    click.option("--signed", is_flag=True, help="Store features as BC6H_SF16 instead of BC6H_UF16 (bc6h only)."),
    click.option("--init", "init", type=click.Choice(list(FEATURE_INITS)), default=DEFAULT_INIT, show_default=True,
                 help="How training starts: 'random' as in the paper, or 'pca' from the texture set's principal "
                      "components and their linear decoder (sharper fine mips, weaker coarse ones)."),
    click.option("--fix-nonfinite", is_flag=True,
                 help="Replace NaN/Inf texels of float sources (NaN by 0, +-Inf by the channel's largest / "
                      "smallest finite value) instead of refusing them (exit 2)."),
    click.option("--seed", type=int, default=DEFAULT_SEED, show_default=True,
                 help="Random seed (CPU runs are deterministic)."),
    click.option("--device", default=DEFAULT_DEVICE, show_default=True, help="auto, cpu or cuda[:N]. auto trains on CUDA when torch sees a GPU; the CPU presets "
                      "train faster with --device cpu (the fused kernel) even there (README, CUDA)."),
    click.option("--threads", type=click.IntRange(min=1), default=DEFAULT_THREADS, show_default=True,
                 help="Torch CPU threads per training; 1 trained fastest on a 2-core machine "
                      "(docs/benchmarks.md). Parallelism comes from training materials side by side. "
                      "In a build, never more than --jobs."),
    click.option("--kernel", type=click.Choice([k.value for k in Kernel]), default=DEFAULT_KERNEL.value,
                 show_default=True,
                 help="How a training step runs: fused (one vectorised C++ kernel for features, MLP and gradients, "
                      "6-10x the samples/s of torch on a CPU; built once into the cache, numba where no C++ "
                      "compiler is found), torch (the reference; the only one on CUDA), or auto: fused on the "
                      "CPU, torch on CUDA."),
    click.option("--target-psnr", "target_psnr", type=click.FloatRange(min=0, min_open=True), default=None,
                 metavar="DB",
                 help="Rate control: train the smallest, then quickest, profile and preset predicted to reach DB "
                      "(PSNR over all mips of the exported files), instead of --profile and --quality. A probe "
                      "training (or --bench-data) predicts; a miss climbs to the next setting. docs/rate_control.md."),
    click.option("--layout", type=click.Choice([v.value for v in Layout]), default=None,
                 help="auto (the default; neural with --target-psnr): per material, keep as classic BC textures "
                      "the channel groups the features lose, or BC@R's own levels for the closest mips (a mip split), "
                      "and pick the profile, by the highest PSNR over all mips within the size of the BC set you "
                      "would ship (BC@R) and 0.5 dB of it at every mip; BC@R's groups repacked as BC7 in the same "
                      "bytes are weighed too. Never worse than BC@R, which it ships when nothing else qualifies. A "
                      "probe training and at most one more (docs/layout.md). neural: "
                      "every output from the MLP."),
    click.option("--match-bc", "match_bc", is_flag=True,
                 help="With --layout auto: the smallest layout whose every mip reaches BC@R instead."),
    click.option("--classic", "classic", multiple=True, default=(), metavar="SEMANTICS",
                 help="Keep these channel groups as the classic BC textures BC@R has (BC1, BC4, BC5, BC6H for HDR colour, every mip), "
                      "by semantic, comma-separated or repeated, e.g. normal or opacity; a packed file's group (ARM) goes whole "
                      "when one of its semantics is named. The rest is neural, or chosen by --layout auto. "
                      "Materials without such a channel train as they would without it."),
    click.option("--bench-data", "bench_data", type=click.Path(dir_okay=False, exists=True), default=None,
                 metavar="BENCH_JSON",
                 help="With --target-psnr: predict from the measured cells of this `bcfpipe bench` report "
                      "(its bench.json) for a texture set with the same source files, instead of a probe."),
)
def training_record(ctx: click.Context) -> tuple[TrainingOptions, dict | None]:
    """The command's `TrainingOptions`, made (and so validated) once from its parameters of the same
    names, and the bench report to predict --target-psnr from, if any. --target-psnr together with
    an explicit --profile or --quality is refused: it chooses them."""
    options = TrainingOptions(**{f.name: ctx.params[f.name] for f in fields(TrainingOptions)})
    if options.target_psnr is None:
        return options, None
    given = [f"--{'quality' if n == 'preset' else n}" for n in ("profile", "preset")
             if ctx.get_parameter_source(n) not in (ParameterSource.DEFAULT, None)]
    if given:
        raise InputError(f"--target-psnr chooses the profile and preset itself; drop {' and '.join(given)}")
    if options.bench_data is None:
        return options, None

    return options, read_report(options.bench_data)


def training_options(f):
    """Decorate a command with every training option (`TRAINING_OPTIONS`)."""
    for opt in reversed(TRAINING_OPTIONS):
        f = opt(f)
    return f


def _variants(_ctx: click.Context, _param: click.Parameter, values: tuple[str, ...]) -> dict[str, str]:
    """Parse repeated ``--variant SET=VALUE`` into a dict; a malformed one, or two values for one
    set, exits 2."""
    from bcfpipe.scan.composition import parse_variants  # lazy: start-up

    return parse_variants(values)


variant_option = click.option(
    "--variant", "variants", multiple=True, callback=_variants, metavar="SET=VALUE",
    help="Select VALUE in variant set SET on every prim offering it (repeatable, one value per set).")
all_materials_option = click.option(
    "--all-materials", is_flag=True, help="Also model materials not bound to rendered geometry.")
material_option = click.option(
    "--material", "materials", multiple=True, metavar="PRIM",
    help="Only this material (its prim path, as `scan` lists it; repeatable). The others are reported "
         "as skipped: not-selected.")

texel_density_option = click.option(
    "--texel-density", "texel_density", type=click.FloatRange(min=0, min_open=True), default=None,
    metavar="PX_PER_M",
    help="Texels per metre the scene needs (e.g. 512): each material's texture set is resampled to the "
         "smallest power of two that meets it on its most demanding mesh, never above the source, and its "
         "profile follows. Without it nothing is capped (the scan still reports each density).")

"""The `sinrun` command: parse, call one library function, report.

Heavy imports (torch, onnxruntime, trimesh) happen inside the commands, so
`--help` is instant and everything but `train` works without torch.
"""

import dataclasses
import functools
import math
import os
import signal
import sys
import time
from pathlib import Path

import click

from sinshape.core import files
from sinshape.core.errors import ConflictError, InputError, NamesParameters, spelled

from sinshape.runtime.options import ASSET_OPTIONS, OPTION

from .params import FRACTIONS, SEEDS, TILES, named_output, request_option, table_option
from .progress import StageProgress, TrainProgress, format_seconds, progress_bar

# The options of a sample request (runtime/options.py) the command line takes in
# a form of its own: {option: (its parameter, its flag)}. The others are
# `request_option`s, named as the table names them.
SPELLED = {"layout": ("layout_file", "--layout"), "tile": ("tiles", "--tiles"), "heights": ("height_map", "--map"),
           "models": ("others", "MODEL..."), "models_map": ("models_map", "--models-map")}
# Library parameters the command line spells otherwise than as an option of
# their own name: how a message naming one says it.
RENAMED = {**{name: flag for name, (_, flag) in SPELLED.items()}, "factors": "--size", "alpha": "--range"}


@functools.cache
def option_names() -> dict:
    """{parameter: the option that sets it} for every option of every
    command, and RENAMED: how the command line writes the names a library
    message marks. Not a seed: a sample's comes from --seed, --seeds or
    --keep, a run's from train's --seed."""
    names = {param.name: next(opt for opt in param.opts if opt.startswith("--"))
             for command in cli.commands.values() for param in command.params
             if isinstance(param, click.Option) and param.name != "seed"}
    return {**names, **RENAMED}


# ctx.meta key: {parameter: what set it} where a command's value came from elsewhere than its option.
SOURCES = "sinrun.sources"
# The extra that installs each optional module (pyproject.toml): a command
# that needs a missing one says which extra to install.
EXTRAS = {"torch": "train", "onnx": "train", "scipy": "prep", "h5py": "prep", "skimage": "prep",
          "fastapi": "serve", "uvicorn": "serve", "starlette": "serve", "ray": "ray", "xatlas": "assets",
          "meshoptimizer": "assets"}


def command_line_message(error: Exception | str, options: dict | None = None) -> str:
    """The error's (or a note's) message with each parameter it names (core.errors marks
    them) written as the option that sets it: an InputError's, or any other's
    that names one the same way (training's stops)."""
    template = error.template if isinstance(error, NamesParameters) else str(error)
    options = option_names() if options is None else options
    message = spelled(template, lambda name: options.get(name, name))
    return message.replace("\r", "\\r").replace("\n", "\\n")  # one line, whatever a value held


class Sinrun(click.Group):
    """Turns InputError (bad user input) into one line and exit code 1."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except InputError as error:
            # A command may say that a value came from elsewhere than its option.
            options = {**option_names(), **ctx.meta.get(SOURCES, {})}
            raise click.ClickException(command_line_message(error, options)) from None
        except ModuleNotFoundError as error:
            top = (error.name or "").partition(".")[0]
            if top not in EXTRAS:
                raise
            raise click.ClickException(f"this needs {top}, which is not installed: "
                                       f"pip install 'sinshape[{EXTRAS[top]}]'") from None
        except ImportError as error:  # a signal while a compiled module (onnxruntime) initialises
            stop = interruption(error)
            if stop is None:
                raise
            exit_stopped(stop)
        except KeyboardInterrupt as stop:
            exit_stopped(stop)


def interruption(error: BaseException):
    """The Ctrl-C or SIGTERM behind an import that failed, anywhere down its
    chain of causes (onnxruntime turns one that lands while it imports numpy
    into a fresh ImportError), or after either signal was seen; else None."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    if stopped.first is None:
        return None
    return Terminated() if stopped.first == signal.SIGTERM else KeyboardInterrupt()


def exit_stopped(stop: BaseException, message: str | None = None) -> None:
    """Exit as a shell reports the signal that came first: 143 after SIGTERM
    (Terminated), 130 after Ctrl-C."""
    terminated = stopped.first == signal.SIGTERM if stopped.first else isinstance(stop, Terminated)
    click.echo(message or ("terminated" if terminated else "interrupted"), err=True)
    sys.exit(143 if terminated else 130)


@click.group(cls=Sinrun, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="sinshape", prog_name="sinrun")
def cli():
    """Learn to generate new 3D shapes from one example shape.

    Train a model on one mesh (needs the train extra: pip install
    'sinshape[train]'), then sample new shapes from it anywhere, without torch.
    """


class Command(click.Command):
    """A sinrun command: parameters the library refuses together
    (ConflictError) are a misuse of the command, reported with its usage."""

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except ConflictError as error:
            options = {name: "--" + name.replace("_", "-") for name in error.parameter}
            raise click.UsageError(command_line_message(error, {**options, **option_names()}), ctx) from None


cli.command_class = Command


class TrainCommand(Command):
    """`sinrun train --help` ends with what --device auto and --precision auto
    pick on this machine, and why (it imports torch only then)."""

    def format_epilog(self, ctx, formatter):
        try:
            from sinshape.trainer import device
        except ImportError:
            picked = "PyTorch is not installed here: pip install 'sinshape[train]'"
        else:
            picked = device.choose().describe()
        with formatter.section("On this machine"):
            formatter.write_text(f"--device auto --precision auto picks {picked}.")


ASSET_FOLDER_OPTION = click.option(
    "--asset-folder", type=click.Path(file_okay=False, path_type=Path), default=None,
    help="The folder the files a mesh names (an .obj's .mtl and textures, a .gltf's buffers and images) must lie "
         "in, links followed. Default: the mesh's own folder; give a folder above it for textures kept beside it "
         "(../textures/wall.png).")


@cli.command(cls=TrainCommand)
@click.argument("input_path", metavar="INPUT", type=click.Path(path_type=Path))
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Where to write the model (.onnx). A checkpoint MODEL.ckpt.pt is kept beside it.")
@click.option("--preset", type=click.Choice(["default", "paper", "tiny"]), default=None,
              help="Named settings: 'default' (res 64, 1000 iterations per level: a CPU-friendly "
                   "run), 'paper' (res 128, 2000 iterations, as Wu & Zheng 2022), 'tiny' "
                   "(res 32, 2 levels, 10 iterations: a smoke test). Default: default.")
@click.option("--res", type=int, default=None,
              help="Voxels along the longest side of the finest level (meshes only; an .h5 "
                   "pyramid has its own).")
@click.option("--levels", type=int, default=None,
              help="Number of levels. Default: enough that the coarsest longest side is at most 33 voxels.")
@click.option("--iters", type=int, default=None, help="Training iterations per level (3 D + 3 G steps each).")
@click.option("--minutes", type=float, default=None,
              help="A time budget for the whole run instead of --iters: the seconds per iteration of "
                   "the coarse levels are measured first (2% of the budget, at least 20 s) and the large "
                   "ones estimated from them, then each level gets the same number of iterations so that "
                   "training ends within the budget (a busy machine gives fewer iterations). A budget too "
                   "small for --min-iters per level is refused before training, with what would fit; one "
                   "that gives fewer than 300 per level, which real shapes need, is warned about. The plan "
                   "and what was done are printed and saved in the model (sinrun info).")
@click.option("--min-iters", type=click.IntRange(min=1), default=None,
              help="With --minutes: the fewest iterations per level worth training (default 50).")
@click.option("--device", default="auto", show_default=True,
              help="auto, cpu, cuda or cuda:N. auto: CUDA when torch sees a GPU, else the CPU. The "
                   "model and its samples do not depend on it; --resume may continue on another device.")
@click.option("--precision", type=click.Choice(["auto", "fp32", "bf16"]), default=None,
              help="auto (default): bf16 autocast for the convolutions on CPUs with native bf16 "
                   "(AVX512-BF16, AMX) and TF32 on CUDA, float32 otherwise; fp32: float32 throughout.")
@click.option("--box", type=click.IntRange(min=0), default=None,
              help="At levels larger than this many voxels per side, each step sees random boxes of this "
                   "side instead of the whole grid, so an iteration costs what a box costs. 0: whole "
                   "grids, as the paper. Default: the preset's.")
@click.option("--train-depth", type=click.IntRange(min=1), default=None,
              help="Levels trained at once: the newest at the level's rate, each older one at a tenth "
                   "of the next (as ConSinGAN). Default: the preset's, 1: one at a time with the older "
                   "ones frozen, as the paper. More fits the example faster and varies less: 3 made "
                   "copies of a rock arch in 10 minutes.")
@click.option("--lr", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Adam's learning rate for generator and critic, the same at every level. Default: "
                   "the paper preset's 1e-4; the default preset sets each level's rate from its "
                   "iterations (0.1 / iterations, from 1e-4 to 1e-3: 1e-4 at its 1000, up to 1e-3 in "
                   "a short --minutes budget). A fixed 1e-3 over more than about 400 iterations per "
                   "level makes copies of the example.")
@click.option("--d-steps", type=click.IntRange(min=1), default=None,
              help="Critic updates per iteration, before the generator's 3. Default: 3, as the paper. "
                   "Fewer make an iteration cheaper (the critic's gradient penalty is most of its cost).")
@click.option("--d-rate", type=click.FloatRange(min=0, min_open=True), default=None,
              help="The critic's learning rate as a multiple of the generator's. Default: 1, as the paper.")
@click.option("--seed", type=int, default=None, help="Seed of the training run (weights, noise draws). Default 0.")
@click.option("--up", type=click.Choice(["y", "z"]), default=None,
              help="Which axis of the input points up, recorded in the model for viewers and pictures. "
                   "Default: y for a mesh (most .obj files; the shapes of `sinrun shape` are z-up); for "
                   "an .h5 pyramid y (SSG's convention), or z where its lowest z slice is solid ground "
                   "and its lowest y slice is not. `sinrun orient` changes it later, without retraining.")
@click.option("--generator", type=click.Choice(["triplane", "voxel"]), default=None,
              help="triplane (the method) or voxel: the paper's SinGAN-3D baseline, 3-D convs on voxels, "
                   "for comparisons; it writes a .pt checkpoint (-o baseline.pt), not an .onnx model.")
@click.option("--no-colour", "no_colour", is_flag=True,
              help="Train geometry only, reading no colour. By default a mesh with colour (vertex colours, "
                   "or a base-colour texture of a .glb/.gltf, or of an .obj with its .mtl and image) "
                   "trains a coloured model, and colour that cannot be read is an error.")
@click.option("--colour-mb", "colour_mb", type=float, default=None,
              help="The most MB a coloured example's colour tiles may take in the model (the example's colour "
                   "at its own detail, which samples read: docs/METHOD.md). Default 48: a 1024-pixel texture "
                   "at res 48 keeps its full detail in about 24.")
@ASSET_FOLDER_OPTION
@click.option("--resume", is_flag=True,
              help="Continue an interrupted run from its checkpoint, skipping finished levels, "
                   "with the checkpoint's settings. Refused when the mesh or the files it names have changed.")
@click.option("--checkpoint", type=click.Path(path_type=Path), default=None,
              help="Checkpoint file. Default: MODEL.ckpt.pt beside the output.")
@click.option("--quiet", "-q", is_flag=True, help="No progress output.")
def train(input_path, output, preset, device, no_colour, asset_folder, resume, checkpoint, quiet, **settings):
    """Train a model on one example shape and export it as one .onnx file.

    INPUT is a mesh (.obj, .ply, .stl, .off, .glb; not necessarily watertight)
    or an SSG voxel pyramid (.h5). The mesh is voxelised at every level of a
    pyramid; one tri-plane generator per level is trained, coarse to fine.
    Checkpoints are written after every level and every 5 minutes; Ctrl-C
    saves one and stops; --resume continues.
    """
    from sinshape.trainer import config as configs, rewind, train as training

    config = configs.make_config(preset, resume, **settings)  # every other option is a TrainConfig field
    if settings["levels"] is None:  # an .h5 file with fewer levels blames where the count came from
        click.get_current_context().meta[SOURCES] = {
            "levels": "the checkpoint's levels" if resume else f"the {preset or 'default'} preset's levels"}
    try:
        with TrainProgress(quiet=quiet) as progress:
            manifest = training.train(input_path, output, config, resume=resume, device=device, colour=not no_colour,
                                      checkpoint_path=checkpoint, progress=progress, log=progress.log,
                                      asset_folder=asset_folder)
    except training.Interrupted as error:  # Ctrl-C or `kill` (Terminated): a checkpoint was saved
        exit_stopped(error.__context__, command_line_message(error))
    except rewind.TrainingDiverged as error:  # option_names has no seed: sample's come from --seed, --seeds, --keep
        raise click.ClickException(command_line_message(error, {"seed": "--seed"})) from None
    sizes = ", ".join("x".join(map(str, level["size"])) for level in manifest["levels"])
    said = "coloured, " if "colour" in manifest else "with its example's relief, " if "relief" in manifest else ""
    click.echo(f"wrote {output} ({said}{len(manifest['levels'])} levels: {sizes}; "
               f"trained in {format_seconds(manifest['training']['seconds'])})")


MODEL_ARGUMENT = click.argument("model", required=False)
THREADS_OPTION = click.option("--threads", type=int, default=None,
                              help="onnxruntime threads per stage. Default: all cores.")
SCALE_OPTION = request_option("scale")
SIZE_OPTION = request_option("size", default="1")


def mesh_options(command):
    """Options shared by the commands that write meshes: how a sample's surface is made."""
    for option in reversed([request_option("smooth"), request_option("smoother"), request_option("largest"),
                            request_option("detail"),
                            request_option("frame", type=click.Choice(OPTION["frame"].choices[:2]))]):
        command = option(command)
    return command


# How the command line shows an asset option beyond its table record.
ASSET_SETTINGS = {"lods": dict(metavar="N,N,..."), "height": dict(metavar="METRES"),
                  "collision": dict(metavar="TRIANGLES"), "hulls": dict(metavar="N")}


def asset_options(kind: str):
    """The options of a game asset of a `kind` of request
    (runtime.options.ASSET_OPTIONS: a .glb with levels of detail and baked
    maps), each made from its record, given to the command as one `asset`
    (asset.AssetOptions, None for a plain file): a new asset option reaches
    the command line without a line here."""
    offered = [option for option in ASSET_OPTIONS if kind in option.goes_with]

    def decorate(command):
        @functools.wraps(command)
        def with_asset(**values):
            from sinshape.runtime import asset

            return command(asset=asset.options_of(**{option.name: values.pop(option.name) for option in offered}),
                           **values)

        for option in reversed(offered):
            text = option.help if option.name == "lods" else f"With --lods: {option.help[0].lower()}{option.help[1:]}"
            default = f" Default {option.default}." if option.default not in (None, False, 0) else ""
            with_asset = table_option(dataclasses.replace(option, help=text + default), default=None,
                                      show_default=False, **ASSET_SETTINGS.get(option.name, {}))(with_asset)
        return with_asset
    return decorate


RESTART_OPTION = click.option(
    "--restart", is_flag=True,
    help="Make every file again where the index beside the outputs records another job (another model, seed, "
         "request or file name), which a rerun otherwise refuses, naming the difference.")


def open_model(model, threads):
    from sinshape import models
    from sinshape.runtime import load

    return load.load_model(models.find(model), threads=threads)


# What `sample` says of a request option beyond the table's words.
SAMPLE_SETTINGS = {"size": dict(default="1"), "frame": dict(type=click.Choice(OPTION["frame"].choices[:2])),
                   "keep": dict(more_help="The model's frame is the units of its meshes and `sinrun info`. The box "
                                          "less a 4-voxel join is exactly SEED's."),
                   "grow": dict(more_help="2,1,1 doubles the sample (of --seed, at --size) along x.")}


def sample_options(command):
    """Every option of a sample request (runtime/options.py: all but those
    of a tile alone), each made from the table, but those SPELLED otherwise: a new
    option reaches `sample` and its request without a line here."""
    for option in reversed(OPTION.values()):
        if option.goes_with != ("tile",) and option.name not in SPELLED:
            command = request_option(option.name, **SAMPLE_SETTINGS.get(option.name, {}))(command)
    return command


@cli.command()
@MODEL_ARGUMENT
@sample_options
@click.option("--seeds", type=SEEDS, default=None,
              help="Many samples, one file each: 0-99 or 1,5,9-12. A resumable job: see --engine.")
@click.option(*reversed(SPELLED["layout"]), type=click.Path(path_type=Path), default=None,
              help="Generate with the structure of this layout (.vox or .npz, from `sinrun layout`, edited "
                   "as you like; or a rough mesh, a few boxes in the model's frame, voxelised on the coarsest "
                   "level's grid); --seed still varies the detail.")
@click.option("--resample-layout", is_flag=True,
              help="Fit a layout whose grid is not one of the model's levels to level 0's grid.")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help=f"Output file: .ply (streamed to disk slab by slab, any size) or "
                   f"{' '.join(suffix for suffix in files.MESH_FORMATS if suffix != '.ply')} (made whole in memory), "
                   f"or {' '.join(files.GRID_FORMATS)} (the occupancy grid). With --seeds, {{seed}} in the name is "
                   "replaced, or _seedN is added. Default: MODEL_seedN.ply.")
@asset_options("sample")
@THREADS_OPTION
@click.option("--workers", type=int, default=None,
              help="With --seeds: worker processes (--engine local; default: one per core) or Ray actors "
                   "(--engine ray; default: one per CPU of the cluster), each loading the model once.")
@click.option("--engine", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="With --seeds: this machine's cores, or a Ray cluster (pip install 'sinshape[ray]'). "
                   "Files are written atomically and an index (JSON lines) beside them records each "
                   "seed; a rerun skips the seeds already done.")
@click.option("--address", default=None,
              help="With --engine ray: the cluster's address. Default: Ray's own (RAY_ADDRESS, else a "
                   "local Ray on this machine).")
@RESTART_OPTION
def sample(model, seeds, layout_file, resample_layout, output, asset, threads, workers, engine, address, restart,
           **fields):
    """Generate new shapes from a model and write them as meshes.

    MODEL is a .onnx file from `sinrun train` or the name of a shipped model
    (`sinrun models` lists them); without it, the default shipped model.
    Needs no torch.
    """
    from sinshape.runtime import layout_files, write
    from sinshape.runtime.request import Layout, SampleRequest

    if seeds is None and (workers is not None or engine != "local" or address is not None or restart):
        raise ConflictError("`workers`, `engine`, `address` and `restart` are for many samples: give `seeds`",
                            ("workers", "engine", "address", "restart", "seeds"))
    loaded = open_model(model, threads)
    laid_out = Layout.of(layout_files.read_any(loaded, layout_file, fields["size"]), resample_layout) if layout_file else None
    request = SampleRequest.of({**fields, "layout": laid_out})
    show_warnings(loaded, request)
    output = output or Path(f"{loaded.path.stem}_{'recon' if request.recon else 'seed{seed}'}."
                            f"{'glb' if asset else 'ply'}")
    if seeds:
        return sample_seeds(loaded, seeds, output, engine, workers, threads, address, request, restart, asset)
    path = named_output(output, seed=request.sample_seed) if "{" in str(output) else output
    with StageProgress() as show:
        note = write.write_request(loaded, request, path, [layout_file] if layout_file else [], threads,
                                   lambda done, total: show("meshing", done, total), asset)
    report_written(path, note)


def sample_seeds(model, seeds, output, engine, workers, threads, address, request, restart=False,
                 asset=None) -> None:
    """`sinrun sample --seeds`: one resumable job, one progress bar."""
    from sinshape.runtime import many, write

    if request.scale > 2 and write.output_kind(output) == "mesh":
        say_how_long(model, seeds, request)
    if "{" in output.name:
        named_output(output, seed=0)  # only {seed} may be filled in
        pattern = output
    else:
        pattern = output.with_name(f"{output.stem}_seed{{seed}}{output.suffix}")
    run_job(lambda progress: many.sample_many(model.path, iter(seeds), pattern, engine, workers, threads, address,
                                              progress=progress, request=request, restart=restart, asset=asset),
            seeds, "seeds", lambda seed: named_output(pattern, seed=seed))


def run_job(job, items, unit: str, name) -> None:
    """Run a resumable job of many files, `job(progress)`, under one progress
    bar counting `items` (with a rate of `unit` per second); then say what
    it wrote, `name(item)` for the first and last."""
    started, made = time.monotonic(), [0]

    def rate(_):
        seconds = time.monotonic() - started
        return f"{made[0] / seconds:.2f} {unit}/s" if made[0] and seconds > 0 else ""

    with click.progressbar(length=len(items), label="sampling", file=sys.stderr, show_pos=True,
                           item_show_func=rate, hidden=len(items) < 2 or not sys.stderr.isatty()) as bar:
        def progress(item, record):
            made[0] += record is not None
            bar.update(1, item)

        result = job(progress)
    skipped = f", {result['skipped']} already done" if result["skipped"] else ""
    click.echo(f"wrote {result['written']} files{skipped}: {name(items.first)} .. {name(items.last)}; "
               f"index {result['index']}")


# What `world` says of a request option beyond the table's words.
WORLD_SETTINGS = {
    "seed": dict(default=0, help="The world's seed: the same seed, the same world."),
    "frame": dict(more_help="A tile in the training mesh's frame or finest voxels is placed where it lies in the world "
                            "(near the origin: float32 cannot place tiles far out); with 'tile' the index gives each "
                            "tile's corner."),
    "arrange": dict(default=None, show_default=False,
                    more_help="Default: what the model records (`sinrun orient --arrange`), else blend."),
}


def world_options(command):
    """Every option of a tile request (runtime/options.py), each made from
    the table, but those SPELLED otherwise: a new option of a tile reaches
    `world` and its request without a line here."""
    for option in reversed(OPTION.values()):
        if "tile" in option.goes_with and option.name not in SPELLED:
            command = request_option(option.name, **WORLD_SETTINGS.get(option.name, {}))(command)
    return command


@cli.command()
@MODEL_ARGUMENT
@click.argument(SPELLED["models"][0], nargs=-1, metavar="[MODEL]...")
@world_options
@click.option(*reversed(SPELLED["tile"]), type=TILES, required=True, metavar="I0:I1,J0:J1",
              help="The tiles to write, both ends included: -8:8,-8:8 is 17 x 17 tiles around the origin; 3,4 "
                   "is one. A tile is half the training extent along each horizontal axis.")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="A folder (made if missing) for TILE_I_J files of --format, or a file name holding {tile} "
                   "(world/{tile}.glb); an index (JSON lines) beside them makes a rerun skip what is done. Or "
                   "one mesh file (block.ply): the block as one surface, placed in the world. Default: "
                   "MODEL_world_seedN/.")
@click.option("--format", "suffix", type=click.Choice(files.OUTPUT_FORMATS), default="ply",
              show_default=True, help="The tiles' format, for a folder: a mesh, or npz for the occupancy grid.")
@THREADS_OPTION
@click.option("--workers", type=int, default=None,
              help="Worker processes (default: one, on every core's threads: neighbouring tiles share work a "
                   "worker keeps, which workers taking tiles in turn would each do again) or Ray actors.")
@click.option("--engine", type=click.Choice(["local", "ray"]), default="local", show_default=True,
              help="This machine's cores, or a Ray cluster (pip install 'sinshape[ray]').")
@click.option("--address", default=None, help="With --engine ray: the cluster's address.")
@click.option(*reversed(SPELLED["heights"]), type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="The world's large shape: a greyscale .png (black low, white --relief voxels high; columns "
                   "along the first horizontal axis, rows up the second, from the world's origin; each pixel a "
                   "square of the tiles' longer side, which `sinrun info` gives) or a .npy array of heights in "
                   "voxels, [i, j] for pixel i,j. Beyond it, its edge goes on.")
@click.option("--relief", type=float, default=None,
              help="Voxels from a .png map's black to its white. Default: 4 times the model's height.")
@click.option(SPELLED["models_map"][1], type=click.Path(exists=True, dir_okay=False, path_type=Path), default=None,
              help="Which model goes where in a scattered world: a model's index per pixel (0 the first "
                   "model), as a palette or greyscale .png (a pixel's value is the index, laid out as --map's) or "
                   "a .npy array of indices, [i, j] for pixel i,j; each object is drawn from the model its cell's centre's "
                   "pixel names. The other models follow the first: sinrun world FIRST SECOND ... --arrange "
                   "scatter --models-map map.png.")
@RESTART_OPTION
@asset_options("tile")
def world(model, others, tiles, output, suffix, threads, workers, engine, address, height_map, relief, models_map,
          restart, asset, **fields):
    """Write tiles of an endless world: any tile on its own, seamless with its neighbours.

    The world spreads along the model's two horizontal axes (the two that are
    not its up axis: `sinrun info` names it). Every tile depends only on the
    model, the seed, the map and its place, so tiles join without a crack
    whatever was made before, and a tile a billion tiles away costs what
    tile 0,0 costs. Several models scatter their objects over one world
    where a model map says: sinrun world FIRST SECOND --arrange scatter
    --models-map map.png.
    """
    from sinshape import models
    from sinshape.runtime import many, request as requests, write

    loaded = open_model(model, threads)
    wanted = requests.world_request(loaded, fields, height_map, relief, [models.find(other) for other in others],
                                    models_map)
    output = output or Path(f"{loaded.path.stem}_world_seed{wanted.sample_seed}")
    suffix = "glb" if asset else suffix
    if output.suffix.lower() in files.MESH_FORMATS and "{tile}" not in output.name:  # one mesh of the block
        if asset:
            raise InputError(f"{output}: a block of tiles is one mesh; write its tiles as assets to a folder or a "
                             "name holding {tile}", "lods")
        with StageProgress() as show:
            write.write_block(loaded, wanted, tiles, output, lambda done, total: show("tiles", done, total))
        return click.echo(f"wrote {output} ({len(tiles)} tiles)")
    pattern = output if "{tile}" in output.name else output / f"tile_{{tile}}.{suffix}"
    run_job(lambda progress: many.write_tiles(loaded.path, iter(tiles), pattern, wanted, engine, workers, threads,
                                              address, progress, restart, asset),
            tiles, "tiles", lambda tile: pattern.with_name(pattern.name.replace("{tile}", f"{tile[0]}_{tile[1]}")))


@cli.command("layout")
@MODEL_ARGUMENT
@click.option("--seed", type=int, default=0, show_default=True, help="The sample whose layout to write.")
@click.option("--level", type=int, default=0, show_default=True,
              help="Which level's grid: 0 is the coarsest (where the big parts are); finer levels give finer control.")
@SIZE_OPTION
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="The layout: .vox (MagicaVoxel and other voxel editors) or .npz (an array 'layout').")
def layout_command(model, seed, level, size, output):
    """Write a sample's coarse layout, to edit and then sample from with `sample --layout`.

    The layout is the sample's occupancy averaged over one level's grid: where
    its towers, columns, bays and gaps are. Remove, duplicate, move or add
    voxels in any voxel editor; `sinrun sample MODEL --seed N --layout FILE`
    then makes a shape with that structure and the model's detail.
    """
    from sinshape.runtime import layout_files

    loaded = open_model(model, threads=None)
    files.check_writable(output, [loaded.path])
    shape = layout_files.export(loaded, seed, output, level, size)
    click.echo(f"wrote {output} ({'x'.join(map(str, shape))} voxels, level {level})")


@cli.command()
@MODEL_ARGUMENT
@click.option("--seeds", type=int, nargs=2, required=True, help="The two seeds to blend, e.g. --seeds 3 7.")
@click.option("--steps", type=click.IntRange(1, 10000), default=9, show_default=True,
              help="How many shapes along the way (at most 10000: more are indistinguishable, and each is a file).")
@click.option("--range", "alpha_range", type=float, nargs=2, default=(-0.5, 1.5), show_default=True,
              help="Blend weights from..to; outside 0..1 extrapolates beyond the two seeds.")
@SCALE_OPTION
@SIZE_OPTION
@click.option("-o", "--output", type=click.Path(path_type=Path), default=Path("interp.ply"), show_default=True,
              help="Output name; _stepK_aALPHA is added for each shape (or fill {step} and {alpha}).")
@mesh_options
@THREADS_OPTION
def interpolate(model, seeds, steps, alpha_range, scale, size, output, smooth, smoother, largest, detail, frame,
                threads):
    """Blend the coarse noise of two seeds: shapes morphing from one to the other.

    The input noise is (1 - a) z0(A) + a z0(B); the finer levels' noise of
    seed A is held fixed, so the shapes change smoothly.
    """
    from sinshape.runtime import generate, write
    from sinshape.runtime.request import SampleRequest

    if not all(map(math.isfinite, alpha_range)):
        raise click.BadParameter(f"--range must be two finite numbers, got {alpha_range[0]} {alpha_range[1]}")
    alpha = generate.blend_weights(*alpha_range, steps)  # refused before a name is made from them
    loaded = open_model(model, threads)
    request = SampleRequest(seeds[0], size=size, scale=scale, smooth=smooth, smoother=smoother, largest=largest,
                            detail=detail, frame=frame)
    show_warnings(loaded, request)

    def path(k):
        return named_output(output, step=f"{k:02d}", alpha=f"{alpha(k):+.2f}")

    with progress_bar(steps, "interpolating") as bar:
        write.write_interpolation(loaded, request, seeds[1], alpha, steps, path, progress=lambda: bar.update(1))
    click.echo(f"wrote {steps} files: {path(0)} .. {path(steps - 1)}")


def say_how_long(model, seeds, request) -> None:
    """'about N minutes' on stderr before a long sampling run, measured on the first seed."""
    from sinshape.runtime import mesh
    from sinshape.runtime.request import make

    count = len(seeds)
    triplane = make(model, request.with_seed(seeds.first), output="planes")  # each seed's own output is checked as made
    seconds = mesh.estimate_seconds(model, triplane, request.scale) * count
    if seconds > 30:
        click.echo(f"--scale {request.scale:g}: about {format_seconds(seconds)} (h:mm:ss) "
                   f"for {count} sample{'s' if count > 1 else ''}", err=True)


def report_written(path, note: str | None = None) -> None:
    """`wrote PATH`, after a note (on stderr) of what was made other than asked (an asset's levels capped)."""
    if note:
        click.echo(f"Note: {command_line_message(note)}", err=True)
    click.echo(f"wrote {path}")


def show_warnings(model, request) -> None:
    """The runtime's warnings about a request (a size or scale clamped), each on a line of stderr."""
    from sinshape.runtime.request import warnings

    for said in warnings(model, request):
        click.echo(f"Warning: {command_line_message(said)}", err=True)


@cli.command()
@MODEL_ARGUMENT
def info(model):
    """Show how a model was made: levels, sizes, training input, config, time."""
    from sinshape.core.manifest import describe, printable

    from sinshape.runtime import world

    loaded = open_model(model, threads=1)
    click.echo(printable(loaded.path))
    for line in describe(loaded.manifest.raw):
        click.echo("  " + line)
    click.echo(f"  {'tiles':<11} {world.tiles_said(loaded)}")


@cli.command()
@MODEL_ARGUMENT
@click.option("--up", type=click.Choice(["y", "z"]), default=None,
              help="The axis of the model's training input that points up.")
@click.option("--arrange", type=click.Choice(["blend", "scatter"]), default=None,
              help="How the model's world is made unless `sinrun world --arrange` says: blend (a landscape: "
                   "terrain, rock) or scatter (one object: a temple, a tower).")
@click.option("--contrast", type=float, default=None,
              help="A blended world's contrast exponent (0.5 to 4; a model without one: 1.3): higher keeps "
                   "more relief where windows blend, in the middle of a tile. benchmarks/world.py's repetition "
                   "section measures it: the relief at tile centres against corners.")
@click.option("--object-scale", type=float, default=None,
              help="How big the model's objects stand in a scattered world of several models: one of its "
                   "voxels spans this many of the world's, against the world's first model's (1/16 to 16; a "
                   "model without one: 1). 0.5 makes its towers half as tall beside the first model's temples.")
@click.option("-o", "--output", type=click.Path(path_type=Path), default=None,
              help="Where to write the changed model (.onnx). Default: the model's own file, changed in "
                   "place (never a shipped model's).")
def orient(model, up, arrange, contrast, object_scale, output):
    """Record which axis of a model points up, or how its world is made, without retraining.

    Viewers, pictures, the page and Blender stand a model's samples on that
    axis; `sinrun world`, the page and Blender make its world as it says
    unless told otherwise. Samples themselves do not change: the same seed
    gives the same shape, in the same coordinates.
    """
    from sinshape import models
    from sinshape.runtime import load

    target = models.own_file(model, output)
    load.write_oriented(open_model(model, threads=1), up, target, arrange, contrast, object_scale)
    said = [f"{up} points up"] * (up is not None) + [f"its world {arrange}s"] * (arrange is not None)
    if contrast is not None:
        said.append(f"blend contrast {contrast:g}")
    if object_scale is not None:
        said.append(f"object scale {object_scale:g}")
    click.echo(f"wrote {target} ({', '.join(said)})")


@cli.command()
@click.argument("inputs", metavar="MESH_OR_MODEL...", nargs=-1, required=True)
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True, help="The picture (.png).")
@click.option("--seeds", type=SEEDS, default="0-3", show_default=True,
              help="Samples to draw from each model input: 0-3 or 1,5,9.")
@click.option("--recon", is_flag=True, help="Draw each model's reconstruction of its training shape first.")
@SCALE_OPTION
@SIZE_OPTION
@request_option("smooth")
@request_option("detail")
@click.option("--views", type=int, default=1, show_default=True,
              help="Views per shape, turning around the up axis (a turntable row per shape).")
@click.option("--up", type=click.Choice(["y", "z"]), default=None,
              help="Which axis points up: y for most .obj files, z for voxel data and the example shapes. "
                   "Default: what the first model input records (models trained from .h5 pyramids: z), "
                   "else y.")
@click.option("--columns", type=int, default=4, show_default=True, help="Shapes per row (with one view each).")
@click.option("--image-size", type=int, default=320, show_default=True, help="Pixels per shape, square.")
@click.option("--zoom", type=float, default=1.0, show_default=True,
              help="Show only a box 1/ZOOM the size of each shape: a close-up.")
@click.option("--focus", type=FRACTIONS, default="0.5,0.5,0.5", show_default=True,
              help="Where the --zoom box is centred, as fractions of the shape's bounding box per axis.")
@click.option("--azimuth", type=float, default=35.0, show_default=True, help="Camera angle around the up axis.")
@click.option("--elevation", type=float, default=25.0, show_default=True, help="Camera angle above the ground.")
@ASSET_FOLDER_OPTION
@THREADS_OPTION
def render(inputs, output, seeds, recon, scale, size, smooth, detail, views, up, columns, image_size, zoom, focus,
           azimuth, elevation, asset_folder, threads):
    """Draw shaded pictures of meshes or of a model's samples, headless.

    Each input is a mesh file (drawn as it is, in its colours: vertex colours
    or its texture, as training reads them) or a model (.onnx or a shipped
    name; its samples are drawn, labelled by seed). Several inputs make one
    picture, e.g. `sinrun render towerruins.obj towerruins --seeds 1-3`
    shows the training mesh beside three samples.
    """
    from sinshape.runtime import render as draw
    from sinshape.runtime.request import SampleRequest

    if output.suffix.lower() != ".png":
        raise InputError(f"{output}: the picture is written as .png")
    files.check_writable(output, [Path(item) for item in inputs])
    if views < 1 or columns < 1 or image_size < 16:
        raise click.UsageError("--views and --columns must be at least 1, --image-size at least 16")
    draw.check_view(zoom, azimuth, elevation)  # before any model is loaded
    items = [Path(item) if draw.is_mesh_file(item) else open_model(item, threads) for item in inputs]
    with StageProgress() as show:
        picture = draw.draw_shapes(items, seeds, recon, SampleRequest(size=size, scale=scale, smooth=smooth, detail=detail), views,
                                   up, columns, image_size, zoom, focus, azimuth, elevation, progress=show,
                                   asset_folder=asset_folder,
                                   warn=lambda said: click.echo(f"Warning: {command_line_message(said)}", err=True))
    draw.save_png(picture, output)
    click.echo(f"wrote {output} ({picture.shape[1]}x{picture.shape[0]})")


@cli.command()
@click.argument("name")
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="Mesh file to write: .obj .ply .stl .off .glb.")
@click.option("--seed", type=int, default=0, show_default=True, help="Seed of the random details.")
@click.option("--detail", type=int, default=None, help="Resolution or element count; smaller is faster. Default: the demo size.")
def shape(name, output, seed, detail):
    """Write a procedural example shape to train on (z is up).

    NAME is terrain, painted_terrain (with vertex colours), acropolis,
    stairs, wall, cheese, relief_wall (vertex colours; its bricks stand out
    of recessed mortar), brick_ruin or lichen_rock (textured: written as
    .glb, or as .obj beside its .mtl and .png).
    """
    from sinshape.prep import shapes

    from sinshape.core.files import check_writable

    check_writable(output)
    written = shapes.write_shape(name, output, seed=seed, detail=detail)
    click.echo(f"wrote {output} ({len(written.faces)} faces, extents "
               f"{' x '.join(f'{e:.2f}' for e in written.extents)})")


@cli.command(name="eval")
@click.argument("model")
@click.option("--reference", type=click.Path(path_type=Path), required=True,
              help="The training input: a mesh (voxelised as the trainer does, at the model's res) or an "
                   "SSG .h5 pyramid (its finest level).")
@click.option("-n", "--samples", type=int, default=100, show_default=True,
              help="Samples to score (the paper uses 100), seeds --first-seed onwards.")
@click.option("--first-seed", type=int, default=0, show_default=True)
@click.option("--scale", type=float, default=1.0, show_default=True,
              help="Score samples on a finer grid against the mesh voxelised that much finer (meshes only).")
@click.option("--upsample", is_flag=True,
              help="Baseline for --scale: upsample the scale-1 occupancy trilinearly instead of "
                   "querying the tri-planes at the finer scale.")
@click.option("--json", "json_path", type=click.Path(path_type=Path), default=None,
              help="Also write the results, per sample too, as JSON.")
@click.option("--force", is_flag=True,
              help="Score against a reference that is not the model's training input without a warning.")
@THREADS_OPTION
def evaluate(model, reference, samples, first_seed, scale, upsample, json_path, force, threads):
    """Score a model as the paper does: LP-IoU, LP-F-score and diversity.

    LP-IoU / LP-F: the fraction of 11^3 surface patches of each sample that
    match some patch of the reference with IoU / F-score above 0.95 (local
    plausibility); diversity: mean 1 - IoU between samples. Needs no torch.
    """
    from sinshape.runtime.evaluate import evaluate_model

    if samples < 2:
        raise click.UsageError("--samples must be at least 2 (diversity compares samples)")
    loaded = open_model(model, threads)

    def warn(message):
        click.echo(f"Warning: {message} (--force silences this)", err=True)

    with StageProgress() as show:
        results = evaluate_model(loaded, reference, samples, first_seed, scale, upsample, progress=show,
                                 json_path=json_path, warn=None if force else warn)
    click.echo(f"{loaded.path.name} against {Path(reference).name}: {samples} samples of "
               f"{'x'.join(map(str, results['sample_size']))}, reference {'x'.join(map(str, results['reference_size']))}")
    click.echo(f"  LP-IoU     {results['lp_iou']:.3f}")
    click.echo(f"  LP-F       {results['lp_f']:.3f}")
    click.echo(f"  diversity  {results['diversity']:.3f}")
    click.echo(f"  time       {results['seconds_sampling']:.1f} s sampling, {results['seconds_scoring']:.1f} s scoring")


@cli.command()
@click.argument("model_names", metavar="[MODEL]...", nargs=-1)
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on. The default, loopback, is reachable from this machine only; "
                   "another address (0.0.0.0: every interface) exposes the service to the network, "
                   "and it has no authentication.")
@click.option("--port", type=click.IntRange(0, 65535), default=8000, show_default=True, help="Port to listen on.")
@click.option("--timeout", type=float, default=60.0, show_default=True,
              help="Seconds a sample request may take before it is answered 504.")
@click.option("--allowed-host", "allowed_host", multiple=True, metavar="NAME",
              help="A name clients may reach the server by (the Host header), besides the loopback names "
                   "and --host; repeat for more. Others are answered 400, so that a web page elsewhere "
                   "cannot reach a local server through a name of its own (DNS rebinding).")
@THREADS_OPTION
def serve(model_names, host, port, timeout, allowed_host, threads):
    """Serve models over HTTP: a JSON API and a page to browse samples in 3-D.

    MODEL is a .onnx file or the name of a shipped model; without any, every
    shipped model. Open http://HOST:PORT/ in a browser; the API is described
    at /openapi.json. There is no authentication: anyone who can reach the
    address can use it, so it listens on loopback unless --host says otherwise.
    Needs the serve extra: pip install 'sinshape[serve]'.
    """
    import uvicorn  # noqa: F401 (the serve extra is installed)

    from sinshape.serve import app

    def ready(url, allowed):
        reach = "loopback only" if host in app.LOOPBACK else "reachable from the network"
        click.echo(f"serving {', '.join(loaded)} at {url} (no authentication; {reach}; answering to "
                   f"{', '.join(allowed)}) - Ctrl-C stops", err=True)

    loaded = app.load_models(model_names, threads)
    app.run(loaded, host, port, timeout, allowed_host, ready)


@cli.command(name="export-web")
@click.argument("model_names", metavar="MODEL...", nargs=-1, required=True)
@click.option("-o", "--output", type=click.Path(path_type=Path), required=True,
              help="The folder to write: new, empty, or one export-web wrote before (its files are replaced).")
@click.option("--force", is_flag=True,
              help="Write into a folder that holds other files too: they stay, export-web's own are replaced.")
def export_web(model_names, output, force):
    """Write a static web site that samples models in the browser, with no server.

    MODEL is a .onnx file or the name of a shipped model. The folder holds the
    page, the JavaScript runtime, onnxruntime-web and the models; any static
    file server serves it, offline (python DIR/serve.py compresses). The same
    seed gives the same shape as `sinrun sample`. Its README.txt says how to
    let WASM use several threads.
    """
    from sinshape.serve import site

    from sinshape.runtime import __version__

    result = site.export_site(model_names, output, __version__, force)
    click.echo(f"wrote {output} ({', '.join(result['models'])}; {result['files']} files, "
               f"{result['bytes'] / 2**20:.1f} MB): python {output / 'serve.py'}")


@cli.command(name="models")
def list_models():
    """List the shipped models (sample one with `sinrun sample NAME`)."""
    from sinshape import models

    shipped = models.available()
    if not shipped:
        click.echo("no shipped models are installed")
    for name, path in sorted(shipped.items()):
        marker = " (default)" if name == models.DEFAULT else ""
        click.echo(f"{name}{marker}  {path}")


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised where Ctrl-C would be, so that it unwinds the same way:
    temporary files removed, a training checkpoint saved."""


def stopped(signum, frame):
    """SIGINT and SIGTERM: the first raises (KeyboardInterrupt, Terminated)
    and is remembered in `stopped.first`, since a library may turn it into
    another error (onnxruntime, into an ImportError that does not hold it;
    Ray's wait, into a plain KeyboardInterrupt). Any later one, while the
    command unwinds, is let pass: a second Ctrl-C must not cut short the
    removal of a temporary file or the saving of a checkpoint."""
    if stopped.first is None:
        stopped.first = signum
        raise Terminated if signum == signal.SIGTERM else KeyboardInterrupt


stopped.first = None


def main():
    signal.signal(signal.SIGTERM, stopped)
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not where the shell ignores it
        signal.signal(signal.SIGINT, stopped)
    try:
        cli(prog_name="sinrun")
    except SystemExit as done:
        if done.code or "torch" in sys.modules or "ray" in sys.modules:
            raise
        # A command that succeeded has closed its files (every write is atomic):
        # ending here skips the interpreter's teardown, freeing onnxruntime's
        # sessions and every module one by one, about 80 ms of a 0.45 s sample.
        # Not after training or Ray, whose exit handlers may still have work.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(0)

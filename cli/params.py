"""`sinrun`'s parameter types: seed lists, per-axis values, output names,
and the options of a sample request, made from the runtime's table of them
(runtime/options.py). Values are parsed by the runtime where the web API
reads the same text."""

import itertools
import string
import sys
from pathlib import Path

import click

from sinshape.core.errors import InputError
from sinshape.runtime.options import OPTION

class SeedList:
    """Seeds such as 1,5,9-12 kept as ranges, so that 0-100000000 costs
    nothing until it is iterated."""

    def __init__(self, ranges: list):
        self.ranges = [r for r in ranges if len(r)]

    def __len__(self) -> int:  # at most 2**63 seeds a range; len() of a larger count would overflow
        return min(sum(r.stop - r.start for r in self.ranges), sys.maxsize)

    def __iter__(self):
        return itertools.chain.from_iterable(self.ranges)

    @property
    def first(self) -> int:
        return self.ranges[0][0]

    @property
    def last(self) -> int:
        return self.ranges[-1][-1]


class Seeds(click.ParamType):
    """'3', '0-99' or '1,5,9-12' -> a SeedList."""

    name = "seeds"

    def convert(self, value, param, ctx):
        if isinstance(value, SeedList):
            return value
        try:
            ranges = []
            for part in value.split(","):
                low, _, high = part.strip().partition("-")
                if high and int(high) < int(low):
                    self.fail(f"{value!r}: {part.strip()} counts down; write {high}-{low}", param, ctx)
                ranges.append(range(int(low), int(high or low) + 1))
        except ValueError:
            self.fail(f"{value!r} is not a seed list like 3, 0-99 or 1,5,9-12", param, ctx)
        if any(r.start < 0 or r.stop > 2**63 for r in ranges):  # before len(), which overflows past 2**63
            self.fail(f"{value!r}: seeds are integers in [0, 2**63)", param, ctx)
        seeds = SeedList(ranges)
        if not seeds.ranges:
            self.fail(f"{value!r} gives no seeds", param, ctx)
        return seeds


class PerAxis(click.ParamType):
    """One value for all three axes, or 'a,b,c': parsed by the runtime, which
    reads the same text from the web API."""

    def __init__(self, name: str, parse):
        self.name, self.parse = name, parse

    def convert(self, value, param, ctx):
        if isinstance(value, tuple):
            return value
        try:
            return self.parse(value)
        except InputError as error:
            self.fail(f"{value!r}: {str(error).split(': ', 1)[1]}", param, ctx)


def parse_size(text: str) -> tuple:
    """'2' or '2,1,1' -> per-axis factors of the training size."""
    from sinshape.runtime import generate

    return generate.parse_size(text)


def parse_fractions(text: str) -> tuple:
    """'0.5,0.7,1' -> three numbers in [0, 1]."""
    from sinshape.runtime import generate

    return generate.parse_triple(text, lambda v: 0 <= v <= 1, "three fractions in [0, 1], like 0.5,0.7,1")


class TileBlock:
    """The tiles I0..I1 x J0..J1 (both ends included), row by row, made as
    they are iterated."""

    def __init__(self, rows: range, columns: range):
        self.rows, self.columns = rows, columns

    def __len__(self) -> int:  # len() of a range or a count past 2**63 would overflow
        return min((self.rows.stop - self.rows.start) * (self.columns.stop - self.columns.start), sys.maxsize)

    def __iter__(self):
        return ((i, j) for i in self.rows for j in self.columns)

    @property
    def first(self) -> tuple:
        return self.rows[0], self.columns[0]

    @property
    def last(self) -> tuple:
        return self.rows[-1], self.columns[-1]


class Tiles(click.ParamType):
    """'-8:8,-8:8' (I0:I1,J0:J1, both ends included) or '3,4' (one tile) -> a TileBlock."""

    name = "tiles"

    def convert(self, value, param, ctx):
        if isinstance(value, TileBlock):
            return value
        from sinshape.runtime.world import check_tile

        try:
            ends = [tuple(int(v) for v in part.split(":")) for part in value.split(",")]
            if len(ends) != 2 or not all(len(e) in (1, 2) for e in ends):
                raise ValueError
        except ValueError:
            self.fail(f"{value!r} is not a block of tiles like -8:8,-8:8 or 3,4", param, ctx)
        ends = [(e[0], e[-1]) for e in ends]
        if any(high < low for low, high in ends):
            self.fail(f"{value!r}: a range counts down; write LOW:HIGH", param, ctx)
        try:
            check_tile((ends[0][0], ends[1][0]))
            check_tile((ends[0][1], ends[1][1]))
        except InputError as error:
            self.fail(f"{value!r}: {error}", param, ctx)
        return TileBlock(*(range(low, high + 1) for low, high in ends))


SEEDS, SIZE, FRACTIONS = Seeds(), PerAxis("size", parse_size), PerAxis("fractions", parse_fractions)
TILES = Tiles()


def named_output(output: Path, **fields) -> Path:
    """Fill {seed}-style fields in an output name, or add them before the suffix."""
    if not output.name:  # '.', '/', ''
        raise click.BadParameter(f"{str(output)!r} is not a file name")
    if any("{" + key + "}" in str(output.parent) for key in fields):
        raise click.BadParameter(f"{output}: {', '.join('{' + k + '}' for k in fields)} fills in the file's name, "
                                 f"not its folder {output.parent}")
    if "{" in output.name:
        try:
            if any(name is not None and (name not in fields or spec or conversion)
                   for _, name, spec, conversion in string.Formatter().parse(output.name)):
                raise ValueError("a field other than a plain {name}")
            return output.with_name(output.name.format(**fields))
        except (KeyError, IndexError, ValueError):
            raise click.BadParameter(f"{output.name}: only {', '.join('{' + k + '}' for k in fields)} "
                                     "can be filled in") from None
    tag = "_".join(f"{key}{value}" for key, value in fields.items())
    return output.with_name(f"{output.stem}_{tag}{output.suffix}")


def request_option(name: str, *flags: str, more_help: str = "", **settings):
    """A click option for the sample request's option `name`
    (runtime.options.OPTION): its type, default and help from the table,
    `more_help` added and `settings` (another flag, default or type) taking
    precedence. Its parameter is the option's name unless `settings` names another."""
    return table_option(OPTION[name], *flags, more_help=more_help, **settings)


def table_option(option, *flags: str, more_help: str = "", **settings):
    """A click option for a record of the options table (runtime.options), as request_option."""
    name = option.name
    types = {"seed": int, "int": int, "number": float, "choice": click.Choice(option.choices),
             "factors": FRACTIONS if option.high == 1 else SIZE, "counts": str}
    made = dict(help=" ".join(filter(None, (option.help, more_help))), default=option.default)
    if option.type == "bool":  # a flag; one on by default is turned off by --no-NAME
        made["is_flag"] = True
        if option.default and not flags:
            flags = (f"--{name.replace('_', '-')}/--no-{name.replace('_', '-')}",)
    elif option.type == "parts":
        made.update(multiple=True, metavar="SEED:X0,Y0,Z0:X1,Y1,Z1")
    elif option.type in types:
        made.update(type=types[option.type], show_default=option.default is not None)
    else:
        raise ValueError(f"the command line spells {name} ({option.type}) its own way")
    made.update(settings)
    return click.option(*(flags or ("--" + name.replace("_", "-"),)), made.pop("parameter", name), **made)

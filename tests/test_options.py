"""The table of a sample's options (runtime/options.py) and the front ends held
to it: SampleRequest's fields and checks, the command line, the HTTP routes,
the page's copy of the table; and each refusing a field it does not know.
(The page and its worker in chromium: tests/test_web.py; Blender's settings:
tests/test_blender_options.py.)"""

import dataclasses
import json
from pathlib import Path

import pytest

from sinshape.core.errors import ConflictError, InputError
from sinshape.core.files import OUTPUT_FORMATS
from sinshape.runtime.options import EDITS, OPTION, OPTIONS, module_js
from sinshape.runtime.request import SampleRequest

ROOT = Path(__file__).resolve().parents[1]


def kind_of(option) -> set:
    """The kinds of request an option is for ("sample" for a sample's edits)."""
    return {"sample" if goes in EDITS else goes for goes in option.goes_with}


def test_the_request_has_one_field_per_option_with_its_default():
    fields = dataclasses.fields(SampleRequest)
    assert [field.name for field in fields] == [option.name for option in OPTIONS]
    assert all(field.default == OPTION[field.name].default for field in fields)
    assert SampleRequest() == SampleRequest.of({option.name: option.default for option in OPTIONS})


NUMBERS = [(option.name, end) for option in OPTIONS if option.type in ("seed", "int", "number", "factors")
           for end in ("low", "high") if getattr(option, end) is not None]


@pytest.mark.parametrize("name, end", NUMBERS)
def test_sample_request_checks_each_range_the_table_gives(name, end):
    """A value at a bound is taken where the table says the bound is in, and
    the value just past it is refused, naming the option; a bound left out
    of the range is refused itself."""
    option = OPTION[name]
    value = option.low if end == "low" else option.high
    closed = option.bounds[0 if end == "low" else 1] in "[]"
    step = 1 if option.type in ("seed", "int") else 1e-9
    context = {"grow": 2} if name == "anchor" else {"arrange": "scatter"} if name in ("density", "spacing") else {}
    if closed:
        assert getattr(SampleRequest(**{name: value, **context}), name) in (value, (value,) * 3)
    with pytest.raises(InputError) as refused:
        SampleRequest(**{name: (value - step if end == "low" else value + step) if closed else value, **context})
    assert not isinstance(refused.value, ConflictError) and refused.value.parameter == name


@pytest.mark.parametrize("name", [option.name for option in OPTIONS if option.choices])
def test_sample_request_takes_each_choice_and_no_other(name):
    for choice in OPTION[name].choices:
        assert getattr(SampleRequest(**{name: choice}), name) == choice
    with pytest.raises(InputError) as refused:
        SampleRequest(**{name: "none of them"})
    assert refused.value.parameter == name


def test_a_field_no_option_has_is_refused_not_dropped():
    with pytest.raises(InputError, match=r"^a sample request has no field 'colour'; its fields are seed, recon,") as no:
        SampleRequest.of({"seed": 3, "colour": "example"})
    assert no.value.parameter == "colour"


def test_the_pages_copy_of_the_table_is_the_tables():
    """serve/static/sinshape/options.js is written from the table; a change to one without the other fails here."""
    written = (ROOT / "serve" / "static" / "sinshape" / "options.js").read_text()
    assert written == module_js(), "run: python -m sinshape.runtime.options > serve/static/sinshape/options.js"
    assert all(f"  {json.dumps(option.as_json())}," in written for option in OPTIONS)
    assert f"export const FORMATS = Object.freeze({json.dumps(OUTPUT_FORMATS)});" in written


# ---- the command line


def test_the_command_line_offers_every_option_from_the_table():
    """`sample` takes every option of a sample, `world` every option of a
    tile: each named as the table names it (or as SPELLED says, for the ones
    given as a file or a block of tiles), with the table's help."""
    from sinshape.cli.main import SPELLED, sample, world

    for command, kind in ((sample, "sample"), (world, "tile")):
        params = {param.name: param for param in command.params}
        wanted = {option.name for option in OPTIONS if kind in kind_of(option)}
        named = {SPELLED[name][0] if name in SPELLED else name for name in wanted}
        assert named <= set(params), (command.name, named - set(params))
        extra = {name for name in params if name in OPTION} - wanted  # a request option it is not for
        assert not extra, (command.name, extra)
        for name in wanted - set(SPELLED):
            if name not in ("seed",) or command is sample:  # world's seed is the world's
                assert params[name].help.startswith(OPTION[name].help), (command.name, name)


def test_the_command_line_names_each_option_in_its_errors():
    from click.testing import CliRunner

    from sinshape.cli.main import SPELLED, cli, option_names

    assert all(option_names()[name] == (SPELLED[name][1] if name in SPELLED else f"--{name}") for name in OPTION if name != "seed")
    result = CliRunner().invoke(cli, ["sample", "--smooth", "101", "--smoother", "gauss"])
    assert result.exit_code == 2 and "'gauss' is not one of 'laplacian', 'taubin'" in result.output
    result = CliRunner().invoke(cli, ["world", "--help"])
    assert result.exit_code == 0 and "--arrange [blend|scatter]" in result.output and "--lod INTEGER" in result.output



HOSTILE = (-1, 10**30, float("nan"), "none of them", (0.0, 0.0), ("x",) * 20, object())


@pytest.mark.parametrize("name", [option.name for option in OPTIONS])
def test_every_refusal_of_an_option_names_it_as_each_front_end_spells_it(name):
    """Whatever hostile value an option is given, its refusal marks the
    option's name (core.errors), so the command line writes the option the
    user typed and nothing else: every other word of the sentence stays as
    written (a field name that is also an ordinary word is not one)."""
    from sinshape.cli.main import command_line_message, option_names

    context = {"grow": 2} if name == "anchor" else {"arrange": "scatter"} if name in ("density", "spacing") else {}
    refused = []
    for value in HOSTILE:
        try:
            SampleRequest(**{name: value, **context})
        except InputError as error:
            refused += [error] if error.parameter == name else []
    assert refused, f"no hostile value of {name} is refused as {name}'s"
    flag = option_names().get(name, name)  # a sample's seed has three options: the message keeps its name
    for error in refused:
        assert f"`{name}`" in error.template, error.template
        typed, plain = command_line_message(error), str(error)
        assert "`" not in typed + plain and flag in typed
        assert plain == error.template.replace("`", "") and typed.replace(flag, name) == plain


def test_a_word_that_is_also_a_field_stays_a_word_on_the_command_line():
    from sinshape.cli.main import command_line_message
    from sinshape.runtime.world import HeightMap, WorldOptions

    with pytest.raises(InputError) as heights:
        HeightMap.of([[0.0, float("nan")]])
    assert command_line_message(heights.value) == "a height map holds values in voxels within +-16384: no NaN or infinities"
    with pytest.raises(InputError) as models:
        WorldOptions(arrange="scatter", models=("m.onnx",) * 256)
    assert command_line_message(models.value) == "a world takes at most 255 MODEL... after the first"


# ---- the HTTP routes


@pytest.fixture(scope="module")
def openapi():
    from sinshape.serve.app import create_app

    return create_app({}).openapi()


ROUTE_OWN = {"name", "format", "lods", "texture", "ao", "height", "collision", "hulls", "naming", "quantise", "compress", "ktx2", "resample_layout", "relief", "i", "j"}  # not a request's


@pytest.mark.parametrize("route, kind", [("sample", "sample"), ("tile", "tile")])
def test_the_routes_take_every_option_of_their_kind_from_the_table(openapi, route, kind):
    """GET and POST together take each option of a sample (or a tile) as a
    query parameter of its name, with the table's description and range, but
    those serve/app.py's SPELLED sends otherwise; and no other option."""
    from sinshape.serve.app import SPELLED

    methods = openapi["paths"][f"/api/models/{{name}}/{route}"]
    params = {param["name"]: param for method in methods.values() for param in method["parameters"]}
    wanted = {option.name for option in OPTIONS if kind in kind_of(option)} - set(SPELLED)
    assert set(params) - ROUTE_OWN == wanted
    for name in wanted - {"seed", "frame"}:  # a tile's frame and a sample's seed say more
        assert params[name]["description"] == OPTION[name].help, name
    schema = params["smooth" if kind == "sample" else "lod"]["schema"]
    option = OPTION["smooth" if kind == "sample" else "lod"]
    assert schema.get("maximum") == option.high and schema["minimum"] == option.low


def test_the_routes_refuse_a_query_parameter_they_do_not_take(tmp_path):
    """A misspelt option, or one this server is too old for, is a 422 naming
    it, not an answer made without it; the page's own query is its state."""
    import asyncio

    from sinshape.serve.app import create_app

    app = create_app({})

    async def get(target: str):
        path, _, query = target.partition("?")
        scope = {"type": "http", "method": "GET", "path": path, "query_string": query.encode(), "root_path": "",
                 "headers": [(b"host", b"127.0.0.1")], "http_version": "1.1", "scheme": "http",
                 "server": ("127.0.0.1", 80), "client": ("127.0.0.1", 1), "asgi": {"version": "3.0"}}
        said = []

        async def receive():
            return {"type": "http.request", "body": b""}

        async def send(message):
            said.append(message)

        await app(scope, receive, send)
        body = b"".join(message.get("body", b"") for message in said if message["type"] == "http.response.body")
        return said[0]["status"], body

    status, body = asyncio.run(get("/api/models/terrain/sample?seed=3&colour=red"))
    assert status == 422 and json.loads(body)["detail"].startswith("colour: this route takes no such query parameter")
    assert asyncio.run(get("/health?verbose=1"))[0] == 422
    assert asyncio.run(get("/api/models/none/sample?seed=3"))[0] == 404  # known parameters: on to the model

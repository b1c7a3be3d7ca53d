"""The Blender extension held to the table of a sample's options
(runtime/options.py): every option is set by one of its settings, left at
its default or set to one value, each setting takes the table's range, and the request it
builds refuses a field no option has. Marked `blender`; skipped where bpy
cannot be imported (Python 3.11 only: the blender extra)."""

import importlib.util

import pytest

from sinshape.core.errors import InputError
from sinshape.runtime.options import OPTION, OPTIONS

HAS_BPY = importlib.util.find_spec("bpy") is not None
pytestmark = [pytest.mark.blender,
              pytest.mark.skipif(not HAS_BPY, reason="needs bpy, Blender as a Python module: "
                                                     "pip install 'sinshape[blender]' (Python 3.11)")]


def test_every_option_is_set_by_a_setting_or_left_at_its_default(addon):
    from blender import convert, props

    groups = [set(convert.SETTINGS), set(convert.LEFT), set(convert.FIXED)]
    assert sum(map(len, groups)) == len(set().union(*groups)) and set().union(*groups) == set(OPTION)
    tile_options = {option.name for option in OPTIONS if "tile" in option.goes_with}
    sample_options = {option.name for option in OPTIONS if "tile" not in option.goes_with or option.name in
                      convert.SAMPLE_TABLE_SETTINGS}
    for name, setting in convert.SETTINGS.items():
        groups = [group for names, group in ((tile_options, props.SinshapeWorld), (sample_options, props.SinshapeSettings))
                  if name in names]
        for group in groups:  # a sample option on a sample object, a tile's on a world (both for seed, scale, detail)
            assert setting in group.__annotations__, (name, setting, group.__name__)


def test_the_settings_take_the_tables_ranges(addon):
    """A sample's and a world's table settings are made from the records:
    their help, default, range and choices (an open end kept just inside)."""
    import bpy

    from blender import convert

    for group, names in (("sinshape", convert.SAMPLE_TABLE_SETTINGS), ("sinshape_world", convert.WORLD_TABLE_SETTINGS)):
        properties = bpy.types.Object.bl_rna.properties[group].fixed_type.properties
        for name in names:
            option, prop = OPTION[name], properties[name]
            assert prop.description == option.help, name
            if option.type == "choice":
                assert [item.identifier for item in prop.enum_items] == list(option.choices), name
            if option.default is not None:
                assert convert.typed(prop.default) == option.default, name
            if option.type in ("int", "number", "seed"):
                inside = 1 if option.type != "number" else 0.01
                low = option.low + (0 if option.bounds[0] == "[" else inside)
                assert prop.hard_min == pytest.approx(low), name
                if option.high is not None and option.high < 2**31:
                    high = option.high - (0 if option.bounds[1] == "]" else inside)
                    assert prop.hard_max == pytest.approx(high), name
    anchor = bpy.types.Object.bl_rna.properties["sinshape"].fixed_type.properties["anchor"]
    assert (anchor.hard_min, anchor.hard_max) == (OPTION["anchor"].low, OPTION["anchor"].high)


def test_the_request_of_settings_refuses_a_field_no_option_has(addon):
    from types import SimpleNamespace

    import numpy as np

    from blender import convert

    kept = SimpleNamespace(seed=3, scale=float(np.float32(1.1)), smooth=2, detail=False)  # Blender keeps 32 bits
    assert convert.table_values(kept, convert.SAMPLE_TABLE_SETTINGS) == dict(seed=3, scale=1.1, smooth=2, detail=False)

    request = convert.sample_request(dict(seed=3, size=(1, 1, 1), scale=1.0, smooth=2), "y")
    assert (request.seed, request.smooth, request.frame) == (3, 2, "input")
    with pytest.raises(InputError, match="no 'colour'"):
        convert.sample_request(dict(seed=3, size=(1, 1, 1), scale=1.0, smooth=2, colour="red"), "y")


def test_the_export_asset_button_offers_every_asset_option_of_the_table(addon):
    """Blender's Export Asset holds a property per asset option
    (runtime.options.ASSET_OPTIONS), with its default where the table has one and its choices."""
    import bpy

    from sinshape.runtime.options import ASSET_OPTIONS

    properties = bpy.ops.sinshape.export_asset.get_rna_type().properties
    for option in ASSET_OPTIONS:
        assert option.name in properties, option.name
        prop = properties[option.name]
        if option.choices:
            assert [item.identifier for item in prop.enum_items] == list(option.choices)
        if option.default not in (None,) and option.name != "lods":
            assert prop.default == option.default, option.name

"""A sinshape object's settings: PropertyGroups on every Object (a
sample's, a world's), saved with the .blend. Changing one that shapes the
sample regenerates the mesh (live.changed; a world's tiles, worlds.changed);
the rest are records (the model file's SHA-256, the applied layout, the
last error)."""

import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, FloatVectorProperty,
                       IntProperty, IntVectorProperty, PointerProperty, StringProperty)

from sinshape import models
from sinshape.runtime.options import ASSET_OPTION, OPTION
from sinshape.runtime.world_maps import MAX_RELIEF

from . import convert, live, worlds

INT_LIMIT = 2**31 - 1  # a Blender integer property's range
SEED_MAX = INT_LIMIT  # the runtime takes seeds up to 2**63
OPEN_MARGIN = 0.01  # Blender's min and max are in the range: an open end of a number's range is kept this far inside


def table_property(option, update=None, **ui):
    """The Blender property of one of the table's options (runtime/options.py):
    its type, default, range, choices and help from the record; `ui` adds or
    replaces what only Blender has (a shorter name, soft limits, a subtype,
    the choices' labels). A plain option is offered in Blender by this call."""
    spec = dict(name=option.name.replace("_", " ").capitalize(), description=option.help)
    if update is not None:
        spec["update"] = update
    if option.type in ("seed", "int", "number"):
        whole = option.type != "number"
        low, high = option.low, option.high
        if low is not None:
            spec["min"] = max(low + (0 if option.bounds[0] == "[" else 1 if whole else OPEN_MARGIN), -INT_LIMIT)
        if high is not None:
            spec["max"] = min(high - (0 if option.bounds[1] == "]" else 1 if whole else OPEN_MARGIN), INT_LIMIT)
        default = option.default or 0  # None, "not given", reads as 0 (asset.options_of: 0 is not given)
        spec["default"] = int(default) if whole else float(default)
        make = IntProperty if whole else FloatProperty
    elif option.type == "bool":
        spec["default"] = option.default
        make = BoolProperty
    elif option.type == "choice":
        spec.update(default=option.default, items=[(choice, choice.capitalize(), "") for choice in option.choices])
        make = EnumProperty
    elif option.type == "counts":
        spec["default"] = ",".join(map(str, option.default or ()))
        make = StringProperty
    else:
        raise TypeError(f"option {option.name}: a {option.type} has no plain Blender property; declare its own")
    return make(**{**spec, **ui})


# What only Blender says of the table's options: the soft range its sliders
# take, a name or default of its own, its choices' labels.
BLENDER_UI = {
    "scale": dict(soft_min=0.25, soft_max=16.0), "smooth": dict(soft_max=20), "spacing": dict(soft_max=12.0),
    "lods": dict(name="Levels", default="20000,5000,1200"), "texture": dict(name="Maps", subtype="PIXEL", min=0),  # 0: sized to the sample
    "ao": dict(name="Ambient occlusion"), "height": dict(min=0.0),  # 0: not given (one unit a metre)
    "collision": dict(description="A collision mesh (positions and triangles, no maps) of this many triangles, "
                      "simplified from the full-resolution surface; 0: the coarsest level's own triangles, its "
                      "vertices shared (no bytes added)"),  # 0: not given, the table's default
    "naming": dict(items=[
        ("gltf", "glTF", "The finest level shown, the coarser ones listed by MSFT_lod and named with Godot's "
         "import hints (Godot 3: one level, the collision a static body), the collision outside the scene"),
        ("godot", "Godot", "As glTF, the collision in the scene too: Godot 4 imports the scene alone "
         "(other importers then draw it)"),
        ("unreal", "Unreal", "The hulls named UCX_: Unreal's convex collision of the finest level")]),
}
RECORDS = {**OPTION, **ASSET_OPTION}  # a sample's options and a game asset's: no name in both


def offering(names, update=None):
    """A class decorator: the class (a PropertyGroup, an operator) gets a
    property per table option of `names`, each made by table_property."""
    def add(cls):
        for name in names:
            cls.__annotations__[name] = table_property(RECORDS[name], update, **BLENDER_UI.get(name, {}))
        return cls
    return add


def model_names(settings, context, text):
    """The model field's suggestions: the shipped models."""
    return sorted(models.available())


def model_changed(settings, context):
    settings.model_sha256 = ""  # a model chosen (again) is taken as it is now
    live.changed(settings, context)


def world_model_changed(settings, context):
    settings.model_sha256 = ""
    worlds.changed(settings, context)


def other_model_changed(other, context):
    other.model_sha256 = ""
    worlds.changed(other.id_data.sinshape_world, context)


@offering(convert.SAMPLE_TABLE_SETTINGS, live.changed)
class SinshapeSettings(bpy.types.PropertyGroup):
    active: BoolProperty(name="sinshape sample", description="This object's mesh is a sinshape sample",
                         default=False)
    model: StringProperty(name="Model", default=models.DEFAULT, search=model_names, update=model_changed,
                          description="A shipped model's name, or a .onnx file (// is the .blend's folder)")
    model_sha256: StringProperty(name="Model SHA-256", description="The model's SHA-256 when it was chosen")
    size: FloatVectorProperty(name="Size", size=3, default=(1.0, 1.0, 1.0), min=0.01, soft_min=0.25, soft_max=4.0,
                              subtype="XYZ", update=live.changed,
                              description="Factors of the training size along Blender's X, Y and Z")
    shade_smooth: BoolProperty(name="Shade smooth", default=True, update=live.changed,
                               description="Smooth shading on the faces")
    edit: EnumProperty(name="Edit", update=live.changed, items=[
        ("NONE", "None", "The plain sample", 0),
        ("KEEP", "Keep", "Keep what a box holds of another seed's sample, the rest from this seed", 1),
        ("GROW", "Grow", "Grow the sample, keeping what it had", 2),
        ("LAYOUT", "Layout", "The structure of an edited coarse layout, the detail from the model", 3)])
    keep_seed: IntProperty(name="Kept seed", min=0, max=SEED_MAX, default=1, update=live.changed,
                           description="The seed whose sample the box keeps")
    keep_box: PointerProperty(name="Box", type=bpy.types.Object, update=live.changed,
                              description="An object whose bounds are the kept box")
    keep_part: StringProperty(name="Kept part", description="The kept box as the request reads it "
                                                            "(SEED:X0,Y0,Z0:X1,Y1,Z1, the model's frame)")
    grow: FloatVectorProperty(name="Grow by", size=3, default=(1.5, 1.0, 1.0), min=1.0, soft_max=4.0,
                              subtype="XYZ", update=live.changed,
                              description="Factors along Blender's X, Y and Z, each at least 1")
    anchor: FloatVectorProperty(name="Anchor", size=3, default=(0.0, 0.0, 0.0), min=OPTION["anchor"].low,
                                max=OPTION["anchor"].high, subtype="XYZ",
                                update=live.changed,
                                description="Where the old sample sits in the grown one, per axis: 0 low, 1 high")
    layout_object: PointerProperty(name="Layout object", type=bpy.types.Object,
                                   description="The cubes of the coarse layout, to edit and apply")
    layout_shape: IntVectorProperty(name="Layout grid", size=3)
    layout_bits: StringProperty(name="Layout", description="The applied layout, packed")
    error: StringProperty(name="Error", description="Why the last regeneration failed")


class SinshapeWorldModel(bpy.types.PropertyGroup):
    """One of a world's models after its first (model 1, 2, ... of its model map), pinned as the first is."""

    model: StringProperty(name="Model", default=models.DEFAULT, search=model_names, update=other_model_changed,
                          description="A shipped model's name, or a .onnx file (// is the .blend's folder)")
    model_sha256: StringProperty(name="Model SHA-256", description="The model's SHA-256 when it was chosen")


@offering(convert.WORLD_TABLE_SETTINGS, worlds.changed)
class SinshapeWorld(bpy.types.PropertyGroup):
    """A world object's settings (worlds.py): its tiles are its children."""

    active: BoolProperty(name="sinshape world", description="This object's children are tiles of a sinshape world",
                         default=False)
    model: StringProperty(name="Model", default=models.DEFAULT, search=model_names, update=world_model_changed,
                          description="A shipped model's name, or a .onnx file (// is the .blend's folder)")
    model_sha256: StringProperty(name="Model SHA-256", description="The model's SHA-256 when it was chosen")
    models: CollectionProperty(name="Other Models", type=SinshapeWorldModel,
                               description="A scattered world's models after its first: model 1, 2, ... of its "
                                           "model map, the first being 0")
    models_map: StringProperty(name="Model Map", subtype="FILE_PATH", update=worlds.changed,
                               description="Which model goes where in a scattered world: a .png (a palette or "
                                           "greyscale image) or .npy of models' indices, laid as the Height "
                                           "Map's pixels, 0 the first model (// is the .blend's folder)")
    heights: StringProperty(name="Height Map", subtype="FILE_PATH", update=worlds.changed,
                            description="The world's large shape, painted: a greyscale .png (black low, white "
                                        "Relief voxels high) or .npy of heights in voxels, each pixel a "
                                        "square of the tiles' longer side (// is the .blend's folder)")
    relief: FloatProperty(name="Relief", default=0.0, min=0.0, max=MAX_RELIEF, soft_max=400.0,
                          update=worlds.changed,
                          description="Voxels an image height map's white stands for (0: four times the "
                                      "model's height)")
    radius: IntProperty(name="Radius", default=2, min=0, max=worlds.MAX_RADIUS, soft_max=8, update=worlds.changed,
                        description="Tiles kept on each side of the followed point's tile")
    fine: IntProperty(name="Fine Radius", default=1, min=0, max=32, soft_max=8, update=worlds.changed,
                      description="Tiles on each side of the followed point's made at full detail; each tile "
                                  "farther, a level coarser (with a skirt over the crack)")
    follow: PointerProperty(name="Follow", type=bpy.types.Object, update=worlds.changed,
                            description="The object whose place the tiles fill around (the camera, say); "
                                        "none: the 3D cursor")
    error: StringProperty(name="Error", description="Why the last fill failed")


CLASSES = (SinshapeSettings, SinshapeWorldModel, SinshapeWorld)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Object.sinshape = PointerProperty(type=SinshapeSettings)
    bpy.types.Object.sinshape_world = PointerProperty(type=SinshapeWorld)


def unregister() -> None:
    del bpy.types.Object.sinshape_world
    del bpy.types.Object.sinshape
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)

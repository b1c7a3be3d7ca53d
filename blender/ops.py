"""The operators: add a sample or a world (and a world's other models), regenerate, variations, a keep box, the
layout shown as cubes and applied, a game asset exported. Each reports bad input Blender's way
(one line, {'CANCELLED'}, nothing half made) and leaves the work to live."""

from pathlib import Path

import bpy
import numpy as np
from bpy.props import BoolProperty, EnumProperty, FloatVectorProperty, IntProperty, StringProperty

from sinshape import models
from sinshape.core.errors import InputError
from sinshape.runtime.options import ASSET_OPTIONS

from . import convert, live, worlds
from .props import SEED_MAX, model_names, offering


def sample_object(context):
    obj = context.active_object
    return obj if obj is not None and obj.sinshape.active else None


class SampleOperator(bpy.types.Operator):
    """An operator on the active sinshape object."""

    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return sample_object(context) is not None


class AddOperator:
    """What Add > Mesh's sinshape entries share: a model in their redo panel
    (and the new object's table settings, as its object has them), and the
    new object selected alone and active."""

    bl_options = {"REGISTER", "UNDO"}

    model: StringProperty(name="Model", default=models.DEFAULT, search=model_names,
                          description="A shipped model's name, or a .onnx file")

    @staticmethod
    def select(context, obj) -> None:
        for other in context.selected_objects:
            other.select_set(False)
        obj.select_set(True)
        context.view_layer.objects.active = obj


@offering(convert.SAMPLE_TABLE_SETTINGS)
class SINSHAPE_OT_add_sample(AddOperator, bpy.types.Operator):
    """Add a sinshape sample: a mesh object with a model and a seed, made again when they change"""

    bl_idname = "sinshape.add_sample"
    bl_label = "sinshape sample"

    size: FloatVectorProperty(name="Size", size=3, default=(1.0, 1.0, 1.0), min=0.01, soft_max=4.0, subtype="XYZ")

    def execute(self, context):
        settings = dict(model=self.model, size=tuple(self.size),
                        **convert.table_values(self, convert.SAMPLE_TABLE_SETTINGS))
        try:
            model, digest = live.load_file(self.model)
            request = convert.sample_request(settings, model.manifest.up)
            arrays = live.make_mesh(model, request)  # at once, as any Add: later changes are made off the main thread
        except InputError as error:
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        obj = live.new_object(context.collection, f"sinshape {model.path.stem}", arrays,
                              {**settings, "model_sha256": digest}, request)
        obj.location = context.scene.cursor.location
        obj.scale = (convert.object_scale(model.manifest),) * 3
        self.select(context, obj)
        return {"FINISHED"}


@offering(("seed", "scale"))
class SINSHAPE_OT_add_world(AddOperator, bpy.types.Operator):
    """Add a sinshape world: the tiles of an endless world around the 3D cursor (or an object it follows)"""

    bl_idname = "sinshape.add_world"
    bl_label = "sinshape world"

    radius: IntProperty(name="Radius", default=2, min=0, max=worlds.MAX_RADIUS, soft_max=8,
                        description="Tiles kept on each side of the followed point's tile")

    def execute(self, context):
        name = f"sinshape world {Path(self.model).stem}"
        obj = bpy.data.objects.new(name, None)
        obj.empty_display_type = "PLAIN_AXES"
        obj.location = context.scene.cursor.location
        try:
            obj.scale = (convert.object_scale(live.load_file(self.model)[0].manifest),) * 3
        except InputError:
            pass  # refused below, by the world's own checks
        context.collection.objects.link(obj)
        context.view_layer.update()  # its matrix, which places the followed point in the world
        with live.suspended():
            for key in ("model", "seed", "scale", "radius"):
                setattr(obj.sinshape_world, key, getattr(self, key))
            obj.sinshape_world.active = True
        try:
            with live.suspended():  # made as the model records its world unless the arrangement is changed
                obj.sinshape_world.arrange = live.load_settings(obj.sinshape_world)[0].manifest.arrange
            worlds.refresh(obj, context.scene)
        except InputError as error:
            for child in list(obj.children):
                worlds.remove(child)
            bpy.data.objects.remove(obj)  # nothing half made
            self.report({"ERROR"}, str(error))
            return {"CANCELLED"}
        self.select(context, obj)
        return {"FINISHED"}


class WorldOperator(bpy.types.Operator):
    """An operator on the active world (or the world of the active tile)."""

    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return worlds.world_of(context.active_object) is not None


class SINSHAPE_OT_world_model_add(WorldOperator):
    """Add a model to the world, the model map's next index: its objects go where the map names it"""

    bl_idname = "sinshape.world_model_add"
    bl_label = "Add Model"

    def execute(self, context):
        settings = worlds.world_of(context.active_object).sinshape_world
        settings.models.add()
        worlds.changed(settings, context)  # as a changed setting: a refusal goes on the world and in a report
        return {"FINISHED"}


class SINSHAPE_OT_world_model_remove(WorldOperator):
    """Remove this model from the world: the models after it take the index before theirs"""

    bl_idname = "sinshape.world_model_remove"
    bl_label = "Remove Model"

    index: IntProperty(name="Index", min=0, description="Which of the other models: 0 is model 1 of the map")

    def execute(self, context):
        settings = worlds.world_of(context.active_object).sinshape_world
        if self.index >= len(settings.models):
            self.report({"ERROR"}, f"no other model has index {self.index}: the world has {len(settings.models)}")
            return {"CANCELLED"}
        settings.models.remove(self.index)
        worlds.changed(settings, context)
        return {"FINISHED"}


def live_objects(context) -> dict:
    """The selected and active samples and worlds (a tile stands for its world), by name."""
    chosen = {}
    for obj in [*context.selected_objects, context.active_object]:
        obj = worlds.world_of(obj) or (obj if obj is not None and obj.sinshape.active else None)
        if obj is not None:
            chosen[obj.name] = obj
    return chosen


class SINSHAPE_OT_regenerate(bpy.types.Operator):
    """Make the selected sinshape samples and worlds again from their settings and model files"""

    bl_idname = "sinshape.regenerate"
    bl_label = "Regenerate"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return bool(live_objects(context))

    def execute(self, context):
        failures = []
        for obj in live_objects(context).values():
            try:
                if obj.sinshape_world.active:
                    worlds.refresh(obj, context.scene, force=True)
                else:
                    live.regenerate(obj, force=True)
            except InputError as error:
                failures.append(f"{obj.name}: {error}")
        if failures:
            self.report({"ERROR"}, failures[0] + (f" (and {len(failures) - 1} more)" if len(failures) > 1 else ""))
            return {"CANCELLED"}
        return {"FINISHED"}


class SINSHAPE_OT_variations(SampleOperator):
    """Make new samples of other seeds with this one's settings, as objects in a new collection, on every core"""

    bl_idname = "sinshape.variations"
    bl_label = "Variations"

    count: IntProperty(name="Count", default=8, min=1, soft_max=64)
    first_seed: IntProperty(name="First seed", min=0, max=SEED_MAX,
                            description="The seeds are this one and those after it (default: after the sample's)")
    arrange: EnumProperty(name="Arrange", items=[("GRID", "Grid", "In a grid beside the sample"),
                                                 ("PLACE", "In place", "Where the sample is")])

    def execute(self, context):
        obj = sample_object(context)
        first = self.first_seed if self.properties.is_property_set("first_seed") else obj.sinshape.seed + 1
        seeds = range(first, min(first + self.count, SEED_MAX + 1))
        return reported(self, live.variations, context, obj, seeds, self.arrange, f"{obj.name} variations")


class SINSHAPE_OT_keep_box_add(SampleOperator):
    """Add a box over half of the sample: what it holds of another seed's sample is kept; move and scale it"""

    bl_idname = "sinshape.keep_box_add"
    bl_label = "Add Keep Box"

    def execute(self, context):
        obj = sample_object(context)
        corners = np.array([tuple(corner) for corner in obj.bound_box])
        low, high = corners.min(axis=0), corners.max(axis=0)
        high[0] = (low[0] + high[0]) / 2  # the lower half along X
        name = f"{obj.name} keep box"
        box = bpy.data.objects.new(name, bpy.data.meshes.new(name))
        convert.fill_mesh(box.data, convert.CUBE_CORNERS * 2 - 1, convert.CUBE_FACES)
        box.display_type = "WIRE"
        box.hide_render = True
        for collection in obj.users_collection:
            collection.objects.link(box)
        box.parent = obj
        box.location = (low + high) / 2
        box.scale = (high - low) / 2
        context.view_layer.update()  # the box's matrix_world, which places it in the sample's space
        settings = obj.sinshape
        before = settings.keep_box, settings.keep_seed, settings.edit
        with live.suspended():
            settings.keep_box, settings.keep_seed, settings.edit = box, settings.seed + 1, "KEEP"
        done = reported(self, live.regenerate, obj)
        if done == {"CANCELLED"}:  # nothing half made: the box goes, the edit is as it was
            with live.suspended():
                settings.keep_box, settings.keep_seed, settings.edit = before
            mesh = box.data
            bpy.data.objects.remove(box)
            bpy.data.meshes.remove(mesh)
        return done


def reported(operator, function, *args) -> set:
    """function(*args), its InputError reported as one line: {'FINISHED'} or {'CANCELLED'}."""
    try:
        function(*args)
    except InputError as error:
        operator.report({"ERROR"}, str(error))
        return {"CANCELLED"}
    return {"FINISHED"}


@offering([option.name for option in ASSET_OPTIONS])
class SINSHAPE_OT_export_asset(SampleOperator):
    """Write this sample as a game asset, a .glb of levels of detail with UVs and maps baked from the model, and add its levels as objects"""

    bl_idname = "sinshape.export_asset"
    bl_label = "Export Asset"

    filepath: StringProperty(subtype="FILE_PATH", description="The .glb to write")
    filter_glob: StringProperty(default="*.glb", options={"HIDDEN"})
    add_objects: BoolProperty(name="Add to scene", default=True,
                              description="Import the written asset's levels, textured, where the sample is")

    def invoke(self, context, event):
        if not self.filepath:
            self.filepath = f"{sample_object(context).name}.glb"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        # 0 reads as "not given" for the numbers whose 0 the table does not take (a height) or means none.
        values = {option.name: getattr(self, option.name) or None for option in ASSET_OPTIONS}
        return reported(self, live.export_asset, sample_object(context), Path(bpy.path.abspath(self.filepath)),
                        self.add_objects, values)


class SINSHAPE_OT_layout_show(SampleOperator):
    """Show the sample's coarse layout as cubes, one per full cell: delete, duplicate, move or extrude them, then apply"""

    bl_idname = "sinshape.layout_show"
    bl_label = "Show Layout"

    def execute(self, context):
        return reported(self, live.show_layout, sample_object(context))


class SINSHAPE_OT_layout_apply(SampleOperator):
    """Make the sample from the edited layout cubes: their structure, the model's detail"""

    bl_idname = "sinshape.layout_apply"
    bl_label = "Apply Layout"

    def execute(self, context):
        return reported(self, live.apply_layout, sample_object(context))


class SINSHAPE_OT_report(bpy.types.Operator):
    """Report a message of work that finished outside an operator"""

    bl_idname = "sinshape.report"
    bl_label = "sinshape report"
    bl_options = {"INTERNAL"}

    kind: EnumProperty(items=[("ERROR", "Error", ""), ("WARNING", "Warning", ""), ("INFO", "Info", "")])
    message: StringProperty()

    def execute(self, context):
        self.report({self.kind}, self.message)
        return {"FINISHED"}


CLASSES = (SINSHAPE_OT_add_sample, SINSHAPE_OT_add_world, SINSHAPE_OT_world_model_add, SINSHAPE_OT_world_model_remove,
           SINSHAPE_OT_regenerate, SINSHAPE_OT_variations, SINSHAPE_OT_keep_box_add, SINSHAPE_OT_layout_show,
           SINSHAPE_OT_layout_apply, SINSHAPE_OT_export_asset, SINSHAPE_OT_report)

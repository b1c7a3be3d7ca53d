"""The sidebar panel (View3D > Sidebar > sinshape), Add > Mesh's entries,
and the status bar's progress."""

import bpy

from . import convert, work, worlds


class VIEW3D_PT_sinshape(bpy.types.Panel):
    bl_label = "sinshape"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "sinshape"

    def draw(self, context):
        layout = self.layout
        obj = context.active_object
        world = worlds.world_of(obj)
        if world is not None:
            settings = world.sinshape_world
            self.draw_state(settings)
            column = layout.column()
            column.prop(settings, "model")
            for index, other in enumerate(settings.models):  # model 1, 2, ... of the model map
                row = column.row(align=True)
                row.prop(other, "model", text=f"Model {index + 1}")
                row.operator("sinshape.world_model_remove", text="", icon="X").index = index
            column.operator("sinshape.world_model_add", icon="ADD")
            for name in ("models_map", "heights", "relief", *convert.WORLD_TABLE_SETTINGS, "radius", "fine", "follow"):
                column.prop(settings, name)
            layout.operator("sinshape.regenerate", icon="FILE_REFRESH")
            return
        if obj is None or not obj.sinshape.active:
            layout.label(text="Not a sinshape sample")
            layout.operator("sinshape.add_sample", icon="ADD")
            layout.operator("sinshape.add_world", icon="WORLD")
            return
        settings = obj.sinshape
        self.draw_state(settings)
        column = layout.column()
        for name in ("model", "size", *convert.SAMPLE_TABLE_SETTINGS, "shade_smooth"):
            column.prop(settings, name)
        layout.operator("sinshape.regenerate", icon="FILE_REFRESH")
        layout.operator("sinshape.variations", icon="MOD_ARRAY")
        layout.operator("sinshape.export_asset", icon="EXPORT")
        layout.separator()
        layout.prop(settings, "edit", expand=True)
        if settings.edit == "KEEP":
            layout.prop(settings, "keep_seed")
            layout.prop(settings, "keep_box")
            layout.operator("sinshape.keep_box_add", icon="CUBE")
        elif settings.edit == "GROW":
            layout.prop(settings, "grow")
            layout.prop(settings, "anchor")
        row = layout.row(align=True)
        row.operator("sinshape.layout_show", icon="MESH_GRID")
        row.operator("sinshape.layout_apply", icon="CHECKMARK")


    def draw_state(self, settings):
        """The last error, and the running work's progress."""
        layout = self.layout
        if settings.error:
            box = layout.box()
            box.alert = True
            box.label(text=settings.error, icon="ERROR")
        status = work.WORKER.status()
        if status:
            layout.progress(factor=status[1], text=status[0])


def add_menu(menu, context):
    menu.layout.operator("sinshape.add_sample", icon="OUTLINER_OB_MESH")
    menu.layout.operator("sinshape.add_world", icon="WORLD")


CLASSES = (VIEW3D_PT_sinshape,)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.VIEW3D_MT_mesh_add.append(add_menu)
    bpy.types.STATUSBAR_HT_header.append(work.draw_status)


def unregister() -> None:
    bpy.types.STATUSBAR_HT_header.remove(work.draw_status)
    bpy.types.VIEW3D_MT_mesh_add.remove(add_menu)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)

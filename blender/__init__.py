"""sinshape in Blender: a sample is a live object with a model and a seed.

Add > Mesh > sinshape sample makes one (sinshape world, the tiles of an
endless world around a point); its settings (the object's
`sinshape` properties, saved with the .blend) make its mesh again when they
change, off the main thread. The add-on converts and calls the torch-free
runtime (bundled as wheels by tools/build_blender.py); how it works:
docs/BLENDER.md.
"""

import bpy
from bpy.app.handlers import persistent

from sinshape.core.errors import InputError

from . import live, ops, props, ui, worlds


@persistent
def opening(*_):
    live.forget()
    worlds.forget()


@persistent
def opened(*_):
    live.check_models()
    worlds.opened()


@persistent
def moved(scene, depsgraph):
    """A sample refused in edit mode has left it: make it. A keep box (or
    its sample) moved: regenerate that sample; one whose
    kept part did not change makes nothing (live.regenerate). A world
    fills the tiles around its followed point (worlds.follow). The updates
    are read first: a world's refresh removes objects they name."""
    if live.SUSPENDED:
        return
    live.left_edit_mode()
    names = {update.id.original.name for update in depsgraph.updates
             if isinstance(update.id, bpy.types.Object) and update.is_updated_transform}
    scene_changed = any(isinstance(update.id, bpy.types.Scene) for update in depsgraph.updates)
    worlds.follow(scene, names, scene_changed)
    for obj in scene.objects if names else ():
        settings = obj.sinshape
        if settings.active and settings.edit == "KEEP" and settings.keep_box is not None \
                and {obj.name, settings.keep_box.name} & names:
            try:
                live.regenerate(obj)
            except InputError:
                pass  # recorded on the object; no report for each step of a drag


HANDLERS = ((bpy.app.handlers.load_pre, opening), (bpy.app.handlers.load_post, opened),
            (bpy.app.handlers.depsgraph_update_post, moved))


def register() -> None:
    props.register()
    for cls in ops.CLASSES:
        bpy.utils.register_class(cls)
    ui.register()
    for handlers, handler in HANDLERS:
        handlers.append(handler)


def unregister() -> None:
    for handlers, handler in HANDLERS:
        if handler in handlers:
            handlers.remove(handler)
    live.forget()
    ui.unregister()
    for cls in reversed(ops.CLASSES):
        bpy.utils.unregister_class(cls)
    props.unregister()

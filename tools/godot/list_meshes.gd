# Godot 3's headless check of an imported asset: run as
#   godot3-server --path PROJECT -s list_meshes.gd res://asset.glb
# in a project whose editor import (godot3-server --path PROJECT --editor --quit)
# has run. Prints RESULT and, as JSON, {"meshes": each drawn mesh's name,
# triangles and the widths of its material's albedo and normal textures,
# "collision": each collision shape's body, kind, triangles (a concave
# shape's) and points (a convex shape's)}.
extends SceneTree

func _init():
	var args = OS.get_cmdline_args()
	var scene = load(args[args.size() - 1]).instance()
	var meshes = []
	var collision = []
	for node in _all(scene):
		if node is MeshInstance:
			var material = node.mesh.surface_get_material(0)
			var albedo = material.albedo_texture if material else null
			var normal = material.normal_texture if material and material.normal_enabled else null
			meshes.append({"name": node.name, "triangles": node.mesh.surface_get_array_index_len(0) / 3,
				"albedo": albedo.get_width() if albedo else 0, "normal": normal.get_width() if normal else 0})
		elif node is CollisionShape:
			var faces = node.shape.get_faces().size() / 3 if node.shape is ConcavePolygonShape else 0
			var points = node.shape.points.size() if node.shape is ConvexPolygonShape else 0
			collision.append({"body": node.get_parent().get_class(), "shape": node.shape.get_class(),
				"triangles": faces, "points": points})
	print("RESULT " + to_json({"meshes": meshes, "collision": collision}))
	quit()

func _all(node):
	var nodes = [node]
	for child in node.get_children():
		nodes += _all(child)
	return nodes

"""What bpy builds: the "Woven Fabric" node group, fitted materials and asset libraries, their
rendered previews, colour layers, real-world scale on meshes, the draped preview, the capture rig as
a scene.

Imports: bpy (with bmesh, mathutils, Cycles) and core/; never ui/.
"""

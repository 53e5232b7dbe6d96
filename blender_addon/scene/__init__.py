"""What bpy builds: the "Woven Fabric" node group, fitted materials and asset libraries, the draped
preview, the capture rig as a scene.

Imports: bpy (with bmesh, mathutils, Cycles) and core/; never ui/.
"""

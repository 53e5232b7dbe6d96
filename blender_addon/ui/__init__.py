"""What the user works with: operators, sidebar panels, add-on preferences, scene properties, the
material tools, the sidebar batch and the batch command. Operators read the context, call core/ or
scene/, and report.

Imports: bpy, scene/ and core/.
"""

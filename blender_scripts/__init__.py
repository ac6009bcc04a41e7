"""Code that runs with bpy: build scenes from recipes, place the rig, render passes."""

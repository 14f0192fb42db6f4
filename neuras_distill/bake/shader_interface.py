"""What a bundle's generated fragment shaders (``bake/glsl.py``) and the player's passes (``playback/``) agree
on: which mesh layer a program draws and the coverage each layer writes into the scene pass's alpha. The bundle
bakes these values into its GLSL; the player reads them back when it compiles and blends.
"""

#: ``MESH_LAYER`` values of a two-layer bundle's fragment shader (the default, without a define, is the core).
CORE_VARIANT, SHELL_VARIANT = 0, 1

#: The alpha a two-layer mesh's shell writes (77 / 255, exact in RGBA8); the core and one-layer meshes write 1.
SHELL_COVERAGE = 77.0 / 255.0

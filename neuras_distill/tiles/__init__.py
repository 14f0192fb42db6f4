"""A large scene as tiles: planned on the ground plane, each distilled as its own job, merged into 3D Tiles.

``plan.py`` splits the foreground into tiles and writes ``CITY/plan.json`` (``neuras-distill tiles plan``);
``tile_field.py`` is the field seen through one tile's training box; ``run.py`` distills one tile into
``CITY/tiles/K/`` (``tiles run``), resumable and idempotent; ``tileset.py`` writes the 3D Tiles 1.1 tileset of
the finished tiles (``tiles merge``). docs/formats.md "Tile plans and tilesets" specifies both files.
"""

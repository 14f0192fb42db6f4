"""Exports of a baked bundle for other players: a glTF binary (``gltf``), a static web player (``web``), and the
texture-size limit both keep (``texture_limit``). Exports read bundles (``bake``) and reuse the player's shaders
(``playback``); nothing below imports them."""

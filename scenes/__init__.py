"""Scenes shipped with mi_nest (package data); see ``mi_nest.scene_path``."""

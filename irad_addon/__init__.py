"""Instant Radiosity core: numpy in, numpy out. Only extract.py, engine.py and
properties.py touch bpy."""

"""Importers: scenes of other renderers translated into arlight worlds."""

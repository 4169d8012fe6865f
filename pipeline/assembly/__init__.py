"""The composition root: shared objects (boom, safety model, hole sampling) built from config."""

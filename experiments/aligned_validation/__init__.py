"""How should the substance of an aligned part be decided? Validation renders aligned like exemplars."""

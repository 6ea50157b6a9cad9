"""The subject's fields: what the form and the flags share."""

# What describes the person, not the session: the form's fields that follow the subject id
# (another subject never inherits them).
SUBJECT_FIELDS = (
    "height_m",
    "weight_kg",
    "age",
    "sex",
    "amputee",
    "side",
    "residual_limb_cm",
    "notes",
)
# What is remembered of them between sessions (tui.remembered): notes belong to one trial.
REMEMBERED_FIELDS = tuple(f for f in SUBJECT_FIELDS if f != "notes")

"""The subject's fields: what the form and the flags share."""

# What describes the person, not the session: remembered per subject id.
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

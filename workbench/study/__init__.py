"""Design studies: a study file in, a report, figures and exported controllers out."""

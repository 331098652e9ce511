"""A build as a whole: BuildSettings (every stage's settings, keys and folders) and each
category's model list. Composes every stage, so it sits at the dataset level."""

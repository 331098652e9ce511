"""Luigi tasks (`luigi --module workflows BuildDataset --local-scheduler`)."""

"""Contact sheets of the prepare, render and augment stages: they run those stages on a few
models outside a build, so they sit above every stage (the dataset's and the shapes' sheets,
which only read files, are in pipeline/sheets)."""

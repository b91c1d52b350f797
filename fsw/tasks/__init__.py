"""Executive tasks: thin wrappers that read inputs, call core, write outputs."""

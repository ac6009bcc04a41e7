"""Everything between renders and training: generation driver, EXR helpers, classes, labels, QA."""

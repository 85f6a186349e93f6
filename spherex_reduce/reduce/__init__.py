"""Reduction: the Step protocol, the executor, the pipeline, plugins and the steps."""

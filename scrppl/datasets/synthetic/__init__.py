"""The synthetic multiview dataset: procedural instances of the Savarese categories, rendered off-screen."""

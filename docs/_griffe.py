"""A griffe extension for the API pages: an attribute whose value is an object (a default
solver, a default options object) is not documented by that object's class docstring, which
griffe's inspection would otherwise show as the attribute's own."""

import inspect

import griffe


class NoValueDocstrings(griffe.Extension):
    def on_attribute_instance(self, *, node, attr, **kwargs) -> None:
        value = getattr(node, "obj", None)
        if attr.docstring is None or value is None:
            return
        if attr.docstring.value == inspect.cleandoc(inspect.getdoc(type(value)) or ""):
            attr.docstring = None

"""Plugin modules that the registry's tests load by path; not test modules (one cannot even be imported)."""

collect_ignore = ["broken_import.py", "tiny_plugin.py"]

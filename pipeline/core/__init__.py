"""Cross-cutting plumbing: errors, config loading and validation, file I/O, device."""

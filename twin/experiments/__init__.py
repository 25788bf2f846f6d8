"""The thesis's experimental programme on any device: datasets, protocols, analyses, reports."""

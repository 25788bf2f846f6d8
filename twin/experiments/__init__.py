"""The thesis's experimental programme on any device: protocols, analyses, reports (the datasets
they write and the predictions and fits over them are :mod:`twin.data`)."""

"""Imported first by the fork server of job and validator processes (``proc.PRELOAD``): the
kernel then kills the fork server when the API process dies, even by ``kill -9``.

Without it the fork server outlived the API, and so did its job processes (which die with
their parent, the fork server): after a restart they ran on for up to 25 s, next to the new
attempt of the same job. Importing this anywhere else ties that process to its parent too.
"""

from cascalib.workers import die_with_parent

die_with_parent()

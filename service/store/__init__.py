"""The zarr store of a sweep, and the datasets beside it: one `location.Store` per URL.

`location` (where a store lives, its group, siblings, completion flags), `lock` (the
writer's lock), `layout` (shards and codecs), `template` (the variables and the template
written before any sample), `shards` (whole-shard writes and reads) and `integrity`
(samples verified, labels compared, values checked).
"""

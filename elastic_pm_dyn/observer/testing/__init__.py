"""Test data and evaluation for the observer, outside the product's path: simulated recordings
with sensor models and disturbances (:mod:`.scenarios`, :mod:`.recordings`) and the scores of
a filter run against their truth (:mod:`.evaluation`). The tests, bench/ and the loop demo use
them; the filter never imports them."""

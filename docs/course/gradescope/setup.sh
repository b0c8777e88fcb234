#!/usr/bin/env bash
# Gradescope builds the autograder image with this (Ubuntu): raytile from the course's
# release, and python3 to read the submission's metadata.
set -eu
apt-get update
apt-get install -y --no-install-recommends ca-certificates curl python3
# The raytile binary is uploaded beside this script (a Linux x86_64 release build).
install -m 0755 /autograder/source/raytile /usr/local/bin/raytile

#!/bin/sh
# Assembles and links the test snippets (LLVM's assembler and the linker rustup ships); the
# ELF files are committed, so the tests do not need these tools. Run from this directory.
set -e
LLD=$(ls "$(rustc --print sysroot)"/lib/rustlib/*/bin/rust-lld | head -1)
for source in *.s; do
  name=${source%.s}
  llvm-mc -triple thumbv7em-none-eabihf -mcpu=cortex-m4 -mattr=+vfp4d16sp -filetype=obj "$source" -o "$name.o"
  "$LLD" -flavor gnu --nmagic -e vectors --section-start=.text=0x08000000 -o "$name.elf" "$name.o"
  rm "$name.o"
done

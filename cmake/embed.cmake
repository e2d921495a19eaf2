# cmake -DINPUT=file -DOUTPUT=file.c -DSYMBOL=name -P embed.cmake
# Writes a C file defining `const char SYMBOL[]`: the bytes of INPUT and a
# terminating NUL (an array initializer, not a string literal, so there is
# no length limit under -Wpedantic).
file(READ ${INPUT} hex HEX)
string(REGEX REPLACE "([0-9a-f][0-9a-f])" "0x\\1," bytes "${hex}")
file(WRITE ${OUTPUT} "/* Generated from ${INPUT} by cmake/embed.cmake; do not edit. */\n"
     "const char ${SYMBOL}[] = {${bytes}0x00};\n")

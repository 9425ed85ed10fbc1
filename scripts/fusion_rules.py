#!/usr/bin/env python3
"""Counts what issue 35 point 5 asks for in src/fusion: its settings (fields of
FusionParams and WalkParams), its bare numeric literals outside tests (any
number but 0, 1 and 2, in code, not comments) and its lines (code and tests).

    python3 scripts/fusion_rules.py [ROOT]
"""
import os
import re
import sys

root = sys.argv[1] if len(sys.argv) > 1 else "."
src = os.path.join(root, "src", "fusion")
TRIVIAL = {"0", "1", "2", "0.0", "1.0", "2.0", "0.", "1.", "2."}
num = re.compile(r"(?<![\w.])(\d[\d_]*(?:\.\d+)?(?:e[+-]?\d+)?)(?:_?(?:f32|f64|usize|u32|u8|i32|isize|u64))?(?![\w])")


def strip(line):
    line = re.sub(r'"(?:[^"\\]|\\.)*"', '""', line)
    return line.split("//", 1)[0]


settings, literals, code_lines, test_lines = 0, 0, 0, 0
for dirpath, _, files in os.walk(src):
    for f in sorted(files):
        if not f.endswith(".rs"):
            continue
        path = os.path.join(dirpath, f)
        lines = open(path).read().split("\n")
        in_test = f in ("tests.rs", "ledger_tests.rs")
        struct = None
        for line in lines:
            if re.match(r"\s*#\[cfg\(test\)\]", line):
                in_test = True
            if in_test:
                test_lines += 1
                continue
            code_lines += 1
            m = re.match(r"pub struct (FusionParams|WalkParams)\b", line)
            if m:
                struct = m.group(1)
            elif struct and line.startswith("}"):
                struct = None
            elif struct and re.match(r"\s+pub \w+:", line):
                settings += 1
            for n in num.findall(strip(line)):
                if n.replace("_", "") not in TRIVIAL:
                    literals += 1
print(f"settings {settings}, bare literals {literals}, lines {code_lines} + tests {test_lines}")

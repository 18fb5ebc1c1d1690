"""The machine a measurement names: its CPU's vector width, which sets a kernel's speed."""
import pytest

from core.machine import cpu_description, machine

ZEN3 = "processor\t: 0\nmodel name\t: AMD EPYC\ncpu family\t: 25\nmodel\t\t: 1\nflags\t\t: fpu sse4_2 avx avx2 fma\n"
ZEN4 = ZEN3.replace("model\t\t: 1", "model\t\t: 17").replace("fma", "fma avx512f avx512bw")


@pytest.mark.parametrize(("cpuinfo", "expected"), [
    (ZEN3, "AMD EPYC (family 25, model 1), AVX2"),
    (ZEN4, "AMD EPYC (family 25, model 17), AVX-512"),
    # the second processor's lines are not read: the first one's name and flags stand
    (ZEN3 + "\n" + ZEN4.replace("processor\t: 0", "processor\t: 1"), "AMD EPYC (family 25, model 1), AVX2"),
    ("model name\t: Some CPU\nflags\t: sse4_2\n", "Some CPU, SSE4.2"),
    ("model name\t: Some CPU\n", "Some CPU"),
])
def test_cpu_description_names_the_widest_vector_extension(cpuinfo, expected):
    assert cpu_description(cpuinfo) == expected


def test_machine_names_cores_and_python():
    text = machine()
    assert " cores, " in text and ", Python 3." in text

"""tests/file_seconds.py: a JUnit XML's case times summed per test file, longest first (the order conftest.py gives
`make test`'s workers)."""

from file_seconds import file_seconds


def test_times_are_summed_per_file_and_listed_longest_first(tmp_path):
    xml = tmp_path / "junit.xml"
    xml.write_text('<testsuites><testsuite name="pytest">'
                   '<testcase classname="tests.test_a" name="one" time="1.25"/>'
                   '<testcase classname="tests.test_a" name="two" time="2.0"/>'
                   '<testcase classname="tests.test_b.TestGroup" name="three" time="7.5"/>'
                   '<testcase classname="" name="collected_nothing" time="9.0"/>'
                   '</testsuite></testsuites>')
    seconds = file_seconds(xml)
    assert seconds == {"test_b.py": 7.5, "test_a.py": 3.2}  # 3.25 rounded to one decimal (half to even)
    assert list(seconds) == ["test_b.py", "test_a.py"]

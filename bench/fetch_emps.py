"""
Download the EMPS benchmark records (DATA_EMPS.mat, DATA_EMPS_PULSES.mat) into a directory.

EMPS, the Electro-Mechanical Positioning System of A. Janot, M. Gautier and M. Brunot, "Data
Set and Reference Models of EMPS", Workshop on Nonlinear System Identification Benchmarks,
Eindhoven, 2019 (HAL hal-02178709). The benchmark is published on
https://www.nonlinearbenchmark.org/benchmarks/emps (a zip behind a Google Drive link); the two
.mat files are downloaded here, unchanged, from the public repository
forgi86/sysid-neural-continuous (examples/EMPS/data/), and checked against their SHA-256::

    python bench/fetch_emps.py data/emps
    EMPS_DATA_DIR=data/emps python bench/bench_emps_score.py

The benchmark scripts read any local directory that holds the two files (--emps DIR or
$EMPS_DATA_DIR): a copy from the zip of nonlinearbenchmark.org serves as well.
"""

import argparse
import hashlib
import os
import sys
import urllib.error
import urllib.request

BASE_URL = ('https://raw.githubusercontent.com/forgi86/sysid-neural-continuous/master/'
            'examples/EMPS/data/')
FILES = {
    'DATA_EMPS.mat': '6cf6814ae14618795da0101aae2bb97ff0c6351b0501b5492751b02b07facf7e',
    'DATA_EMPS_PULSES.mat': '0eab75bb1f6b16228ee78791343a88bf9bfd9a51036ac9807d7b5fc11c0e1704',
}


def fetch(directory: str, base_url: str = BASE_URL, timeout: float = 30.0) -> list:
    """
    Download the EMPS files into ``directory`` (created) and return their paths.

    A file already there with the right checksum is kept. Raises SystemExit with a message
    naming the URL and the error when a download fails or a checksum differs.
    """
    os.makedirs(directory, exist_ok=True)
    paths = []
    for name, sha256 in FILES.items():
        path = os.path.join(directory, name)
        if not _matches(path, sha256):
            url = base_url + name
            try:
                with urllib.request.urlopen(url, timeout=timeout) as response:
                    data = response.read()
            except (urllib.error.URLError, OSError) as error:
                raise SystemExit(
                    f'could not download {url} ({error}); download the EMPS zip from '
                    'https://www.nonlinearbenchmark.org/benchmarks/emps by hand and unpack '
                    f'{", ".join(FILES)} into {directory}') from None
            if hashlib.sha256(data).hexdigest() != sha256:
                raise SystemExit(f'{url}: the download is not the published file (SHA-256 '
                                 f'differs from {sha256}); nothing written')
            with open(path, 'wb') as file:
                file.write(data)
        paths.append(path)
    return paths


def _matches(path: str, sha256: str) -> bool:
    if not os.path.isfile(path):
        return False
    with open(path, 'rb') as file:
        return hashlib.sha256(file.read()).hexdigest() == sha256


def main() -> int:
    """Download into the directory given on the command line."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('directory', help='where to write the two .mat files')
    parser.add_argument('--base-url', default=BASE_URL, help='a mirror of the two files')
    arguments = parser.parse_args()
    for path in fetch(arguments.directory, arguments.base_url):
        print(path)
    return 0


if __name__ == '__main__':
    sys.exit(main())

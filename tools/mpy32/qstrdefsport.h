// no port qstrs
